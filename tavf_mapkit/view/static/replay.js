// The replay bar: pick a run, play or drag the time slider; every view given gets showRun(run) and
// showTime(index into run.ego) as the time moves.
(function () {
  "use strict";

  function MapkitReplay(element, runs, loadRun, views) {
    const state = { run: null, index: 0, playing: false, speed: 1, timer: null };
    if (!runs.length) {
      element.hidden = true;
      return state;
    }
    element.hidden = false;
    element.innerHTML =
      "<select id='replay-run' title='run folder'></select>" +
      "<button id='replay-play' type='button' title='play / pause'>&#9654;</button>" +
      "<select id='replay-speed' title='playback speed'><option value='1'>1x</option><option value='5'>5x</option>" +
      "<option value='20' selected>20x</option><option value='60'>60x</option></select>" +
      "<input id='replay-slider' type='range' min='0' max='0' step='1' value='0' aria-label='time'>" +
      "<span id='replay-time'></span><span id='replay-info'></span>";
    const select = element.querySelector("#replay-run");
    const slider = element.querySelector("#replay-slider");
    const play = element.querySelector("#replay-play");
    const speed = element.querySelector("#replay-speed");
    const label = element.querySelector("#replay-time");
    const info = element.querySelector("#replay-info");
    for (const run of runs) {
      const option = document.createElement("option");
      option.value = run.index; option.textContent = run.name;
      select.appendChild(option);
    }
    state.speed = Number(speed.value);

    function show(index) {
      const run = state.run;
      if (!run) return;
      state.index = Math.max(0, Math.min(run.ego.t.length - 1, index));
      slider.value = state.index;
      const ego = run.ego;
      const speedKmh = ego.speed[state.index] === null ? "" : (ego.speed[state.index] * 3.6).toFixed(1) + " km/h";
      label.textContent = "t = " + ego.t[state.index].toFixed(2) + " s  " + speedKmh +
        (ego.road[state.index] !== null ? "  road " + ego.road[state.index] + " lane " + ego.lane[state.index] : "");
      for (const view of views) view.showTime(state.index);
    }

    async function choose(index) {
      stop();
      const run = await loadRun(index);
      state.run = run;
      slider.max = run.ego.t.length - 1;
      const traffic = run.traffic ? run.traffic.frames.length + " traffic frames" : "no traffic";
      info.textContent = "  " + traffic + ", " + (run.udm || []).length + " UDM answers; " + (run.notes || []).join("; ");
      for (const view of views) view.showRun(run);
      show(0);
      return run;
    }

    function stop() {
      state.playing = false;
      play.innerHTML = "&#9654;";
      if (state.timer) cancelAnimationFrame(state.timer);
      state.timer = null;
    }

    function start() {
      if (!state.run) return;
      state.playing = true;
      play.innerHTML = "&#10074;&#10074;";
      const times = state.run.ego.t;
      let last = performance.now();
      let t = times[state.index];
      if (state.index >= times.length - 1) t = times[0];
      const step = (now) => {
        if (!state.playing) return;
        t += (now - last) / 1000 * state.speed;
        last = now;
        const index = window.MapkitIndexAt(times, t);
        show(index);
        if (index >= times.length - 1) { stop(); return; }
        state.timer = requestAnimationFrame(step);
      };
      state.timer = requestAnimationFrame(step);
    }

    slider.addEventListener("input", () => { stop(); show(Number(slider.value)); });
    play.addEventListener("click", () => (state.playing ? stop() : start()));
    speed.addEventListener("change", () => { state.speed = Number(speed.value); });
    select.addEventListener("change", () => choose(Number(select.value)));
    state.show = show;
    state.choose = choose;
    state.ready = choose(runs[0].index);
    return state;
  }

  window.MapkitReplay = MapkitReplay;
})();
