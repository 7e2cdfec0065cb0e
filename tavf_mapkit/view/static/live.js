// The live bar of `twin drive --view`: polls api/live at the drive's view rate and shows the newest state on
// every view given, through the same showRun/showTime as a replay: the live drive is a run whose ego arrays
// grow (the last MAX_TRAIL states, its track) and whose traffic and UDM hold the newest frame and answer.
(function () {
  "use strict";

  const MAX_TRAIL = 20000;  // ego states kept for the track (33 min at 10 Hz); older ones are dropped
  const EGO_KEYS = ["t", "x", "y", "z", "yaw", "speed", "lat", "lon", "road", "lane"];
  // updates a second where the browser draws in software (options.software): each one redraws and composites
  // the page on the CPU, tens of ms of a core, which the simulation beside it needs (docs/view.md, "Cost")
  const SOFTWARE_RATE_HZ = 2;

  function MapkitLive(element, views, options) {
    options = options || {};
    let rate = Math.max(0.1, Math.min(60, options.rate_hz || 10));
    if (options.software) rate = Math.min(rate, SOFTWARE_RATE_HZ);
    // one fetch per update drawn: the server keeps only the newest state, so a slower page skips states and
    // never falls behind
    const period = 1000 / rate;
    const run = { name: "live", ego: {}, traffic: { frames: [] }, udm: [], notes: [] };
    for (const key of EGO_KEYS) run.ego[key] = [];
    const state = { run, seq: -1, updates: 0, finished: false, stopped: false, latest: null, rate_hz: rate };
    element.hidden = false;
    element.innerHTML = "<span id='live-badge' class='live-badge'>LIVE</span><span id='live-time'>waiting for " +
      "the drive&hellip;</span><span id='live-info'></span>";
    const badge = element.querySelector("#live-badge");
    const label = element.querySelector("#live-time");
    const info = element.querySelector("#live-info");
    let resolveFirst;
    state.first = new Promise((resolve) => { resolveFirst = resolve; });

    function show(live) {
      const ego = live.ego;
      for (const key of EGO_KEYS) run.ego[key].push(ego[key]);
      if (run.ego.t.length > MAX_TRAIL) for (const key of EGO_KEYS) run.ego[key].shift();
      run.traffic.frames = live.traffic ? [live.traffic] : [];
      run.udm = live.udm ? [live.udm] : [];
      const index = run.ego.t.length - 1;
      for (const view of views) {
        if (state.updates === 0) view.showRun(run); else view.refreshTrack();
        view.showTime(index);
      }
      state.updates += 1;
      const speed = ego.speed === null ? "" : (ego.speed * 3.6).toFixed(1) + " km/h";
      label.textContent = "t = " + ego.t.toFixed(2) + " s  " + speed + "  road " + ego.road + " lane " + ego.lane;
      const traffic = live.traffic ? live.traffic.ids.length + " SUMO actors" : "no traffic";
      info.textContent = "  " + traffic + (live.udm ? ", " + live.udm.objects.length + " UDM objects" : "") +
        (rate < options.rate_hz ? "  (" + rate + " updates/s: this browser draws without a GPU)" : "");
      if (state.updates === 1) resolveFirst(live);
    }

    function stop(text) {
      state.stopped = true;
      badge.textContent = "ENDED";
      badge.classList.add("ended");
      info.textContent += "  " + text;
    }

    async function poll() {
      const started = performance.now();
      try {
        const response = await fetch("api/live", { cache: "no-store" });
        const live = await response.json();
        state.latest = live;
        if (live.seq !== state.seq && live.ego) {
          state.seq = live.seq;
          if (!state.updates || run.ego.t[run.ego.t.length - 1] !== live.ego.t) show(live);
        }
        if (live.finished) {
          state.finished = true;
          stop("the drive has ended; the view server stops");
          return;
        }
      } catch (error) {
        stop("no answer from the drive (" + error.message + ")");  // it ended and its server with it
        return;
      }
      setTimeout(poll, Math.max(0, period - (performance.now() - started)));
    }

    poll();
    return state;
  }

  window.MapkitLive = MapkitLive;
})();
