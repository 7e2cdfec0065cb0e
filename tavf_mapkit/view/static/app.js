// The live page of `mapkit view` (and of `twin drive --view`): fetches the build's data from the local server
// and wires the 2D map, the 3D view and the replay bar (or the live bar) together. window.mapkit exposes them
// (for people at the console, and tests).
import { MapkitScene3D, rendersInSoftware } from "./scene3d.js";

async function fetchJSON(url) {
  const response = await fetch(url);
  if (!response.ok) throw new Error(url + ": HTTP " + response.status);
  return response.json();
}

function layoutButtons(views) {
  for (const button of document.querySelectorAll("#layout button")) {
    button.addEventListener("click", () => {
      views.dataset.layout = button.dataset.layout;
      for (const other of document.querySelectorAll("#layout button")) other.classList.toggle("on", other === button);
      window.mapkit.map2d.map.invalidateSize();
    });
  }
}

async function main() {
  const options = window.MAPKIT_OPTIONS || {};
  const [mapData, sceneData, runs] = await Promise.all(
    [fetchJSON("api/map"), fetchJSON("api/scene"), fetchJSON("api/runs")]);
  document.title = "mapkit view: " + mapData.name;
  document.getElementById("title").textContent = mapData.name;
  const map2d = window.MapkitMap2D(document.getElementById("map2d"), mapData, options);
  const software = rendersInSoftware();
  const scene3d = new MapkitScene3D(document.getElementById("view3d"), sceneData, { software });
  window.mapkit = { data: mapData, scene: sceneData, map2d, scene3d, software };
  layoutButtons(document.getElementById("views"));
  if (options.live) {  // `twin drive --view`: the bar follows the running drive instead of replaying a run
    window.mapkit.live = window.MapkitLive(document.getElementById("replay"), [map2d, scene3d],
                                          Object.assign({ software }, options.live));
    await scene3d.loaded;
  } else {
    const replay = window.MapkitReplay(document.getElementById("replay"), runs, (i) => fetchJSON("api/runs/" + i),
                                       [map2d, scene3d]);
    window.mapkit.replay = replay;
    await Promise.all([scene3d.loaded, replay.ready]);
  }
  document.body.dataset.ready = "true";
}

main().catch((error) => {
  console.error(error);
  document.getElementById("title").textContent = "error: " + error.message;
});
