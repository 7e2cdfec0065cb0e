// The 2D map of a build (Leaflet): lanes coloured by type, road marks, signals, objects, junction outlines,
// validation findings and repairs as markers with popups, the GNSS trace and its matched path; and a drive
// replayed on it. Used by the live page of `mapkit view` and, with its data embedded, by report/index.html.
// A classic script (no modules) so that the report opens from disk.
(function () {
  "use strict";

  const LANE_COLOURS = {
    driving: "#70747c", bidirectional: "#70747c", entry: "#7d7fa6", exit: "#7d7fa6", onRamp: "#7d7fa6",
    offRamp: "#7d7fa6", connectingRamp: "#7d7fa6", sidewalk: "#c2baa8", walking: "#c2baa8",
    biking: "#5f9f6e", bicycle: "#5f9f6e", parking: "#5b84b8", shoulder: "#8f8877", border: "#7f6c5b",
    curb: "#a6a6a6", median: "#7b915d", restricted: "#a8636e", stop: "#a8636e", tram: "#9c7e52",
    rail: "#9c7e52", bus: "#b36b3c", taxi: "#b36b3c", HOV: "#b36b3c", none: "#4a4c50",
  };
  const OTHER_LANE = "#8a7fa8";
  const SEVERITY = { error: "#e03131", warning: "#f59f00", info: "#339af0" };
  const MARK_COLOURS = { white: "#f1f3f5", standard: "#f1f3f5", yellow: "#ffd43b", red: "#ff6b6b",
                         blue: "#4dabf7", green: "#69db7c", orange: "#ffa94d" };

  function esc(value) {
    return String(value === null || value === undefined ? "" : value).replace(/[&<>"']/g,
      (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
  }

  function where(p) {
    const parts = [];
    if (p.road !== null && p.road !== undefined) parts.push("road " + esc(p.road));
    if (p.lane !== null && p.lane !== undefined) parts.push("lane " + esc(p.lane));
    if (p.s !== null && p.s !== undefined) parts.push("s=" + Number(p.s).toFixed(2));
    if (p.line !== null && p.line !== undefined) parts.push("line " + esc(p.line));
    return parts.join(", ");
  }

  function laneColour(type) { return LANE_COLOURS[type] || OTHER_LANE; }

  function findingPopup(p) {
    return "<div class='popup finding'><b class='rule'>" + esc(p.rule) + "</b> <span class='severity " +
      esc(p.severity) + "'>" + esc(p.severity) + "</span><br><span class='where'>" + where(p) +
      "</span><br>" + esc(p.message) + "</div>";
  }

  function propertiesPopup(title, p) {
    const rows = Object.keys(p).filter((k) => p[k] !== null && p[k] !== "").map(
      (k) => "<tr><td>" + esc(k) + "</td><td>" + esc(p[k]) + "</td></tr>");
    return "<div class='popup'><b>" + esc(title) + "</b><table>" + rows.join("") + "</table></div>";
  }

  function lowerBound(values, t) {  // last index with values[i] <= t (0 if none)
    let lo = 0, hi = values.length - 1;
    if (hi < 0 || t <= values[0]) return 0;
    while (lo < hi) {
      const mid = (lo + hi + 1) >> 1;
      if (values[mid] <= t) lo = mid; else hi = mid - 1;
    }
    return lo;
  }

  function MapkitMap2D(element, data, options) {
    options = options || {};
    const map = L.map(element, { preferCanvas: true, zoomSnap: 0.25, maxZoom: 23 });
    const canvas = L.canvas({ padding: 0.5 });
    // markers people click are DOM elements (findings, repairs, ego) in a pane above the canvas, which
    // would otherwise take their clicks
    map.createPane("markers").style.zIndex = 450;
    const svg = L.svg({ padding: 0.5, pane: "markers" });
    // what a replay or a live drive moves (track, traffic) on a canvas of its own: redrawing it at 10 Hz must
    // not redraw every lane of the map under it
    map.createPane("moving").style.zIndex = 420;
    const moving = L.canvas({ padding: 0.1, pane: "moving" });
    const layers = {};
    const L_ = data.layers;
    if (options.basemap) {
      L.tileLayer("https://tile.openstreetmap.org/{z}/{x}/{y}.png", {
        maxZoom: 23, maxNativeZoom: 19, attribution: "&copy; OpenStreetMap contributors" }).addTo(map);
    }
    map.attributionControl.setPrefix(false);
    if (data.attribution) map.attributionControl.addAttribution(esc(data.attribution));

    layers.lanes = L.geoJSON(L_.lanes, {
      renderer: canvas,
      style: (f) => ({ color: laneColour(f.properties.type), weight: 0.6, opacity: 0.9,
                       fillColor: laneColour(f.properties.type), fillOpacity: 0.8 }),
      onEachFeature: (f, layer) => layer.bindPopup(() => propertiesPopup("lane", f.properties)),
    }).addTo(map);
    layers.junctions = L.geoJSON(L_.junctions, {
      renderer: canvas, interactive: false,
      style: { color: "#ffe066", weight: 1.2, dashArray: "4 3", fill: false },
    }).addTo(map);
    layers.marks = L.geoJSON(L_.marks, {
      renderer: canvas, interactive: false,
      style: (f) => ({ color: MARK_COLOURS[f.properties.color] || "#f1f3f5", weight: 1,
                       dashArray: String(f.properties.type || "").includes("broken") ? "3 4" : null }),
    }).addTo(map);
    const point = (style, title) => ({
      renderer: svg,
      pointToLayer: (f, latlng) => L.circleMarker(latlng, Object.assign({ renderer: svg }, style(f))),
      onEachFeature: (f, layer) => layer.bindPopup(() => propertiesPopup(title(f), f.properties)),
    });
    layers.signals = L.geoJSON(L_.signals, point(() => ({ radius: 4, color: "#212529", weight: 1,
      fillColor: "#fcc419", fillOpacity: 1, className: "signal-marker" }), (f) => "signal " + f.properties.id)).addTo(map);
    layers.objects = L.geoJSON(L_.objects, point(() => ({ radius: 3, color: "#5c3d1e", weight: 1,
      fillColor: "#b08050", fillOpacity: 1, className: "object-marker" }), (f) => "object " + f.properties.id)).addTo(map);
    layers.repairs = L.geoJSON(L_.repairs, point(() => ({ radius: 4, color: "#862e9c", weight: 1,
      fillColor: "#cc5de8", fillOpacity: 0.9, className: "repair-marker" }), (f) => "repair: " + f.properties.repair));
    layers.findings = L.geoJSON(L_.findings, {
      renderer: svg,
      pointToLayer: (f, latlng) => L.circleMarker(latlng, {
        renderer: svg, radius: 7, weight: 2, color: "#ffffff", fillOpacity: 0.95,
        fillColor: SEVERITY[f.properties.severity] || "#868e96",
        className: "finding-marker finding-" + f.properties.severity }),
      onEachFeature: (f, layer) => layer.bindPopup(findingPopup(f.properties)),
    }).addTo(map);
    const overlays = {
      ["lanes (" + L_.lanes.features.length + ")"]: layers.lanes,
      ["junction outlines (" + L_.junctions.features.length + ")"]: layers.junctions,
      ["road marks (" + L_.marks.features.length + ")"]: layers.marks,
      ["signals (" + L_.signals.features.length + ")"]: layers.signals,
      ["objects (" + L_.objects.features.length + ")"]: layers.objects,
      ["findings (" + L_.findings.features.length + ")"]: layers.findings,
      ["repaired roads (" + L_.repairs.features.length + ")"]: layers.repairs,
    };
    if (L_.gnss) {
      layers.matched = L.geoJSON(L_.matched, { renderer: canvas, style: { color: "#15aabf", weight: 3, opacity: 0.8 },
        onEachFeature: (f, layer) => layer.bindPopup(() => propertiesPopup("matched lane", f.properties)) }).addTo(map);
      layers.gnss = L.geoJSON(L_.gnss, {
        renderer: canvas,
        pointToLayer: (f, latlng) => L.circleMarker(latlng, { renderer: canvas, radius: 2.5, weight: 0,
          fillOpacity: 0.9, fillColor: !f.properties.matched ? "#dee2e6" :
            f.properties.distance_m < 1 ? "#40c057" : f.properties.distance_m < 3 ? "#fab005" : "#fa5252" }),
        onEachFeature: (f, layer) => layer.bindPopup(() => propertiesPopup("GNSS fix", f.properties)),
      }).addTo(map);
      overlays["matched path (" + L_.matched.features.length + " lanes)"] = layers.matched;
      overlays["GNSS fixes (" + L_.gnss.features.length + ")"] = layers.gnss;
    }
    L.control.layers(null, overlays, { collapsed: false, position: "topright" }).addTo(map);
    L.control.scale({ imperial: false }).addTo(map);
    addLegend(map, data);
    map.fitBounds(data.bounds, { padding: [10, 10] });

    // --- replay ---
    const replay = { run: null, group: L.layerGroup().addTo(map), traffic: L.layerGroup().addTo(map),
                     udm: L.layerGroup().addTo(map), ego: null };
    function showRun(run) {
      replay.group.clearLayers(); replay.traffic.clearLayers(); replay.udm.clearLayers();
      replay.run = run;
      if (!run) return;
      const track = [];
      for (let i = 0; i < run.ego.t.length; i++) {
        if (run.ego.lat[i] !== null && run.ego.lon[i] !== null) track.push([run.ego.lat[i], run.ego.lon[i]]);
      }
      replay.track = L.polyline(track, { renderer: moving, color: "#51cf66", weight: 2, opacity: 0.7,
                                         interactive: false }).addTo(replay.group);
      replay.ego = L.circleMarker(track[0], { renderer: svg, radius: 7, weight: 2, color: "#ffffff",
        fillColor: "#2b8a3e", fillOpacity: 1, className: "ego-marker" }).addTo(replay.group);
      replay.ego.bindTooltip("ego");
    }
    function refreshTrack() {  // the run's ego arrays grew (a live drive): redraw its track
      const ego = replay.run.ego, track = [];
      for (let i = 0; i < ego.t.length; i++) if (ego.lat[i] !== null && ego.lon[i] !== null) track.push([ego.lat[i], ego.lon[i]]);
      replay.track.setLatLngs(track);
    }
    function showTime(index) {
      const run = replay.run;
      if (!run) return;
      const ego = run.ego;
      if (ego.lat[index] !== null) replay.ego.setLatLng([ego.lat[index], ego.lon[index]]);
      const t = ego.t[index];
      replay.traffic.clearLayers();
      if (run.traffic && run.traffic.frames.length) {
        const frames = run.traffic.frames;
        const frame = frames[lowerBound(frames.map((f) => f.t), t)];
        for (let k = 0; k < frame.ids.length; k++) {
          const person = frame.person[k];
          L.circleMarker([frame.lat[k], frame.lon[k]], { renderer: moving, radius: person ? 3 : 5, weight: 1,
            color: "#212529", fillColor: person ? "#f06595" : "#22b8cf", fillOpacity: 1, interactive: false,
          }).addTo(replay.traffic);
        }
      }
      replay.udm.clearLayers();
      const answers = (run.udm || []).filter((a) => a.t !== null && a.t <= t && a.status === "ok");
      if (answers.length) {
        for (const obj of answers[answers.length - 1].objects) {
          L.circleMarker([obj.lat, obj.lon], { renderer: svg, radius: 4, weight: 1, color: "#212529",
            fillColor: ["#adb5bd", "#adb5bd", "#4dabf7", "#ffa94d", "#ff6b6b"][obj.layer] || "#adb5bd",
            fillOpacity: 1, className: "udm-marker" }).bindPopup(propertiesPopup("UDM object", obj)).addTo(replay.udm);
        }
      }
    }
    return { map, layers, showRun, showTime, refreshTrack, replay };
  }

  function addLegend(map, data) {
    const legend = L.control({ position: "bottomleft" });
    legend.onAdd = function () {
      const div = L.DomUtil.create("div", "legend");
      const types = {};
      for (const f of data.layers.lanes.features) types[f.properties.type] = (types[f.properties.type] || 0) + 1;
      const rows = Object.keys(types).sort().map((t) =>
        "<div><i style='background:" + laneColour(t) + "'></i>" + esc(t) + " " + types[t] + "</div>");
      const severities = Object.keys(SEVERITY).map((s) =>
        "<div><i class='dot' style='background:" + SEVERITY[s] + "'></i>" + s + "</div>");
      const repairs = (data.repair_counts || []).map((r) =>
        "<div>" + esc(r.repair) + (r.count !== null ? " " + esc(r.count) : "") + "</div>");
      div.innerHTML = "<b>" + esc(data.name) + "</b><div class='small'>" + data.lane_count + " lanes" +
        (data.placed_at_null_island ? ", no geoReference: placed at 0&deg;N 0&deg;E" : "") + "</div>" +
        rows.join("") + "<div class='small'>findings (" + (data.findings_total || 0) + ")</div>" +
        severities.join("") + (repairs.length ? "<details class='small'><summary>repairs made by the build (" +
        repairs.length + " kinds)</summary>" + repairs.join("") + "</details>" : "");
      L.DomEvent.disableClickPropagation(div);
      return div;
    };
    legend.addTo(map);
  }

  window.MapkitMap2D = MapkitMap2D;
  window.MapkitIndexAt = lowerBound;
})();
