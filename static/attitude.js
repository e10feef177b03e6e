// The `attitude` engine's part of a machine page. History comes from the JSON API (downsampled by
// the server), then the `live` WebSocket extends it; on a reconnect or a
// `gap` event the missed range is fetched from the history API again.
'use strict';

tn.registerEngine('attitude', {
  // The fleet card's rows from the newest estimate.
  card(a) {
    return [
      ['pitch', `${tn.fixed(a.pitch_deg, 3)}° · ${tn.fixed(tn.mmPerM(a.pitch_deg), 1)} mm/m`],
      ['roll', `${tn.fixed(a.roll_deg, 3)}° · ${tn.fixed(tn.mmPerM(a.roll_deg), 1)} mm/m`],
    ];
  },

  // The engine's section of a machine page.
  page() {
    const root = document.getElementById('machine');
    const MACHINE = root.dataset.machine;
    const API = `/api/v1/machines/${encodeURIComponent(MACHINE)}`;
    const $ = (id) => document.getElementById(id);
    const { fixed, setText } = tn;

    // Most points asked of the history API per window, and most laser
    // samples read for one window (a laser at 1 Hz over 7 days is not drawn
    // whole).
    const HISTORY_POINTS = 1500, BACKFILL_POINTS = 5000, MAX_LASER = 20000;
    const CHART_HEIGHT = 260;

    const state = {
      windowS: 900,
      estimates: new Map(), // t → attitude estimate
      laser: new Map(), // t → laser reading
      latest: null, // newest attitude estimate
      lastLaserT: null, // newest laser sample fetched
      lastLiveT: null, // newest estimate from the socket: where a backfill starts
      model: null,
      modelVersion: null,
      modelFrozen: null,
      connection: 'connecting',
      backfilled: 0,
    };
    const charts = {};
    // For the browser test and anyone debugging in the console.
    window.tunnelnav = { state, charts };

    // ---- connection state -------------------------------------------------
    function setConnection(connection, detail) {
      state.connection = connection;
      tn.showConnection($('conn-state'), connection, detail);
    }

    // ---- charts -------------------------------------------------------------
    const { axis, num } = tn;

    function pointSeries(label, color, size) {
      return { label, stroke: color, paths: () => null, points: { show: true, size, width: 0, fill: color } };
    }

    function windowStart() {
      return tn.clock.now() - state.windowS;
    }

    function timeChart(el, name) {
      const options = {
        width: el.clientWidth || 800,
        height: CHART_HEIGHT,
        scales: {
          x: { time: true, range: (u, lo, hi) => [windowStart(), Math.max(tn.clock.now(), hi || 0)] },
        },
        series: [
          {},
          { label: `fused ${name}`, stroke: tn.css('--fused'), width: 2, spanGaps: true, points: { show: false },
            value: (u, v) => (v == null ? '—' : `${v.toFixed(3)}°`) },
          { label: 'one-step prediction', stroke: tn.css('--pred'), width: 1.5, dash: [6, 4], spanGaps: true,
            points: { show: false }, value: (u, v) => (v == null ? '—' : `${v.toFixed(3)}°`) },
          pointSeries('inclinometer (raw)', tn.css('--raw'), 3),
          pointSeries('laser', tn.css('--laser'), 8),
          // The fused value ± 2σ (pitch_sigma_deg, roll_sigma_deg), shaded between.
          { label: 'fused + 2σ', stroke: tn.css('--fused'), width: 0.5, spanGaps: true, points: { show: false },
            value: (u, v) => (v == null ? '—' : `${v.toFixed(3)}°`) },
          { label: 'fused − 2σ', stroke: tn.css('--fused'), width: 0.5, spanGaps: true, points: { show: false },
            value: (u, v) => (v == null ? '—' : `${v.toFixed(3)}°`) },
        ],
        bands: [{ series: [5, 6], fill: tn.css('--band') }],
        axes: [axis(), axis({ label: `${name} (°)`, size: 64 })],
        cursor: { drag: { x: false, y: false } },
      };
      return new uPlot(options, [[], [], [], [], [], [], []], el);
    }

    // Point lists [[x, y], …], one per series, on the union of their x's,
    // as uPlot's aligned data wants (null where a series has no point).
    function align(lists) {
      const all = [];
      lists.forEach((list, s) => { for (const [x, y] of list) all.push([x, s, y]); });
      all.sort((a, b) => a[0] - b[0]);
      const xs = [];
      const ys = lists.map(() => []);
      for (const [x, s, y] of all) {
        if (xs.length === 0 || xs[xs.length - 1] !== x) {
          xs.push(x);
          for (const column of ys) column.push(null);
        }
        ys[s][xs.length - 1] = y;
      }
      return [xs, ...ys];
    }

    function drawTimeCharts() {
      const from = windowStart();
      for (const [t] of state.estimates) if (t < from) state.estimates.delete(t);
      for (const [t] of state.laser) if (t < from) state.laser.delete(t);
      for (const name of ['pitch', 'roll']) {
        const fused = [], pred = [], raw = [], laser = [], upper = [], lower = [];
        for (const e of state.estimates.values()) {
          if (num(e[`${name}_deg`])) fused.push([e.t, e[`${name}_deg`]]);
          const sigma = e[`${name}_sigma_deg`];
          if (num(e[`${name}_deg`]) && num(sigma)) {
            upper.push([e.t, e[`${name}_deg`] + 2 * sigma]);
            lower.push([e.t, e[`${name}_deg`] - 2 * sigma]);
          }
          if (num(e[`${name}_pred_deg`]) && num(e.pred_t)) pred.push([e.pred_t, e[`${name}_pred_deg`]]);
          if (num(e[`incl_${name}_deg`])) raw.push([e.t, e[`incl_${name}_deg`]]);
        }
        for (const [t, r] of state.laser) if (num(r[`${name}_deg`])) laser.push([t, r[`${name}_deg`]]);
        charts[name].setData(align([fused, pred, raw, laser, upper, lower]));
      }
    }

    let anfisMemberships = -1;
    function anfisChart(el, memberships) {
      const series = [
        {},
        { label: 'modelled correction', stroke: tn.css('--curve'), width: 2, spanGaps: true, points: { show: false },
          value: (u, v) => (v == null ? '—' : `${v.toFixed(4)}°`) },
        pointSeries('training samples (laser − inclinometer)', tn.css('--sample'), 5),
      ];
      for (let i = 0; i < memberships; i++) {
        series.push({ label: `μ${i + 1}`, scale: 'mu', stroke: tn.css('--mf'), width: 1, dash: [3, 3],
          spanGaps: true, points: { show: false }, value: (u, v) => (v == null ? '—' : v.toFixed(2)) });
      }
      const options = {
        width: el.clientWidth || 800,
        height: CHART_HEIGHT,
        scales: {
          x: { time: false, range: (u, lo, hi) => rollRange(lo, hi) },
          mu: { range: [0, 1.05] },
        },
        series,
        axes: [
          axis({ label: 'roll (°)' }),
          axis({ label: 'pitch correction (°)', size: 70 }),
          axis({ scale: 'mu', side: 1, label: 'membership', grid: { show: false }, size: 50 }),
        ],
        cursor: { drag: { x: false, y: false } },
        hooks: { draw: [drawRollMarker] },
      };
      return new uPlot(options, [[], [], [], ...Array(memberships).fill([])], el);
    }

    function currentRoll() {
      return state.latest && num(state.latest.roll_deg) ? state.latest.roll_deg : null;
    }

    function rollRange(lo, hi) {
      const roll = currentRoll();
      if (lo == null || hi == null) {
        if (roll == null) return [-1, 1];
        lo = hi = roll;
      }
      if (roll != null) { lo = Math.min(lo, roll); hi = Math.max(hi, roll); }
      const pad = Math.max(0.05, (hi - lo) * 0.05);
      return [lo - pad, hi + pad];
    }

    // The current roll as a vertical line on the ANFIS chart.
    function drawRollMarker(u) {
      const roll = currentRoll();
      if (roll == null) return;
      const x = u.valToPos(roll, 'x', true);
      if (x < u.bbox.left || x > u.bbox.left + u.bbox.width) return;
      const ctx = u.ctx;
      ctx.save();
      ctx.strokeStyle = tn.css('--marker');
      ctx.fillStyle = tn.css('--marker');
      ctx.lineWidth = 2 * devicePixelRatio;
      ctx.setLineDash([]);
      ctx.beginPath();
      ctx.moveTo(x, u.bbox.top);
      ctx.lineTo(x, u.bbox.top + u.bbox.height);
      ctx.stroke();
      ctx.font = `${12 * devicePixelRatio}px system-ui, sans-serif`;
      ctx.fillText(`roll now ${roll.toFixed(3)}°`, x + 4 * devicePixelRatio, u.bbox.top + 14 * devicePixelRatio);
      ctx.restore();
    }

    function drawAnfis() {
      const model = state.model;
      if (!model) return;
      const memberships = model.memberships || [];
      if (memberships.length !== anfisMemberships) {
        if (charts.anfis) charts.anfis.destroy();
        $('anfis-chart').textContent = '';
        charts.anfis = anfisChart($('anfis-chart'), memberships.length);
        anfisMemberships = memberships.length;
      }
      const curve = (model.curve || []).map((p) => [p.roll_deg, p.correction_deg]);
      const samples = (model.samples || []).map((s) => [s.roll_deg, s.error_deg]);
      const [xs, ...ys] = align([curve, samples]);
      const mfs = memberships.map((m) => xs.map((x) => Math.exp(-(((x - m.centre_deg) / m.width_deg) ** 2))));
      charts.anfis.setData([xs, ...ys, ...mfs]);

      const badge = $('anfis-state');
      if (model.frozen) {
        setText(badge, 'frozen · laser dropout');
        badge.className = 'badge bad';
      } else if (!model.version) {
        setText(badge, 'not trained yet');
        badge.className = 'badge warn';
      } else {
        setText(badge, 'learning');
        badge.className = 'badge ok';
      }
      const offset = num(model.roll_offset_deg) ? ` · roll offset ${model.roll_offset_deg.toFixed(3)}°` : '';
      const temp = num(model.temp_coefficient_deg_per_c) && model.temp_coefficient_deg_per_c !== 0
        ? ` · ${(model.temp_coefficient_deg_per_c * 1000).toFixed(2)} m°/°C about ${model.temp_reference_c.toFixed(1)} °C`
        : ' · no temperature term';
      setText($('anfis-note'),
        `fit RMSE ${fixed(model.fit_rmse_deg, 4)}° · ${samples.length} training samples · ` +
        `${memberships.length} memberships · trained ${model.version || 0} times · correction ${model.correction}${temp}${offset}`);
      drawNoise(model);
    }

    // The noise the filters run with: measured from the readings
    // (noise=adaptive) or the parameters (noise=fixed).
    function drawNoise(model) {
      const n = model.noise;
      if (!n) return;
      const phase = $('noise-phase');
      setText(phase, n.phase === 'vibrating' ? 'vibrating (cutting)' : 'quiet (standing)');
      phase.className = 'badge ok';
      const sd = (x) => `${fixed(x, 4)}°`;
      setText($('noise-pitch'), `${sd(n.incl_pitch_vibrating_deg)} cutting · ${sd(n.incl_pitch_quiet_deg)} standing`);
      setText($('noise-roll'), `${sd(n.incl_roll_vibrating_deg)} cutting · ${sd(n.incl_roll_quiet_deg)} standing`);
      setText($('noise-colour'), num(n.colour_tau_s) && n.colour_tau_s > 0 ? `time constant ${n.colour_tau_s} s` : 'white');
      setText($('noise-motion'),
        `walk ${n.q_pitch_deg2_per_s.toExponential(1)} °²/s · rate walk ${n.q_pitch_rate_deg2_per_s3.toExponential(1)} °²/s³`);
      setText($('noise-bias'), num(model.pitch_bias_deg)
        ? `${model.pitch_bias_deg.toFixed(4)} ± ${fixed(model.pitch_bias_sigma_deg, 4)}°` : '—');
      setText($('noise-laser'), sd(n.laser_deg));
      setText($('noise-note'), n.mode === 'adaptive'
        ? 'measured from the readings; the engine parameters are only priors'
        : 'fixed by the engine parameters (noise=fixed)');
    }

    function createCharts() {
      for (const id of ['pitch-chart', 'roll-chart']) $(id).textContent = '';
      for (const c of Object.values(charts)) c.destroy();
      for (const k of Object.keys(charts)) delete charts[k];
      charts.pitch = timeChart($('pitch-chart'), 'pitch');
      charts.roll = timeChart($('roll-chart'), 'roll');
      anfisMemberships = -1;
      drawTimeCharts();
      drawAnfis();
    }

    const scheduleRedraw = tn.debounce(() => {
      compactIfLarge();
      drawTimeCharts();
      if (charts.anfis) charts.anfis.redraw(false);
    }, 200);

    // ---- data ---------------------------------------------------------------
    function addEstimate(e) {
      if (!e || e.engine !== 'attitude' || !num(e.t)) return;
      state.estimates.set(e.t, e);
      if (!state.latest || e.t >= state.latest.t) {
        state.latest = e;
        showReadouts();
        if (e.model_version !== state.modelVersion || e.laser_ok === state.modelFrozen) fetchModel();
        if (num(e.laser_age_s)) {
          const laserT = e.t - e.laser_age_s;
          if (state.lastLaserT === null || laserT > state.lastLaserT + 1e-3) fetchLaser(laserT);
        }
      }
    }

    function addLaser(r) {
      if (r && r.sensor === 'laser' && num(r.t)) {
        state.laser.set(r.t, r);
        if (state.lastLaserT === null || r.t > state.lastLaserT) state.lastLaserT = r.t;
      }
    }

    let laserBusy = false;
    async function fetchLaser(laserT) {
      if (laserBusy) return;
      laserBusy = true;
      try {
        const from = state.lastLaserT === null ? Math.max(windowStart(), laserT - 1) : state.lastLaserT + 1e-3;
        for (const r of await tn.ndjson(`${API}/readings?sensor=laser&from=${from}&format=ndjson`, MAX_LASER)) addLaser(r);
        scheduleRedraw();
      } catch (e) {
        console.error('laser samples:', e.message);
      } finally {
        laserBusy = false;
      }
    }

    // At most one model request at a time and one a second: a retrain or a
    // dropout change during a request is fetched after it.
    let modelBusy = false, modelAgain = false;
    async function fetchModel() {
      if (modelBusy) { modelAgain = true; return; }
      modelBusy = true;
      try {
        do {
          modelAgain = false;
          const model = await tn.json(`${API}/model`);
          state.model = model;
          state.modelVersion = model.version;
          state.modelFrozen = model.frozen;
          drawAnfis();
          if (modelAgain) await new Promise((resolve) => setTimeout(resolve, 1000));
        } while (modelAgain);
      } catch (e) {
        console.error('model:', e.message);
      } finally {
        modelBusy = false;
      }
    }

    // Loads the window from the history API. With `replace`, what the page
    // holds is swapped for the server's downsampled copy (keeping what came
    // live after it): this bounds memory when a page stays open for days.
    let historyRequest = 0;
    async function loadHistory(replace) {
      const request = ++historyRequest;
      const from = windowStart();
      if (!replace) setText($('history-note'), 'loading history…');
      try {
        const [history, lasers] = await Promise.all([
          tn.json(`${API}/estimates?engine=attitude&from=${from}&max_points=${HISTORY_POINTS}`),
          tn.ndjson(`${API}/readings?sensor=laser&from=${from}&format=ndjson`, MAX_LASER),
        ]);
        if (request !== historyRequest) return; // the window changed meanwhile
        if (replace && history.estimates.length > 0) {
          const lastT = history.estimates[history.estimates.length - 1].t;
          const newer = [...state.estimates.values()].filter((e) => e.t > lastT);
          state.estimates.clear();
          for (const e of newer) state.estimates.set(e.t, e);
        }
        for (const e of history.estimates) addEstimate(e);
        for (const r of lasers) addLaser(r);
        const how = history.downsampled ? ', downsampled by the server keeping each bucket’s extremes' : '';
        const capped = lasers.length >= MAX_LASER ? ` (the first ${MAX_LASER})` : '';
        setText($('history-note'), history.estimates.length === 0
          ? 'no estimates in this window'
          : `history: ${history.estimates.length} estimates${how}; ${lasers.length} laser samples${capped}; then live`);
        drawTimeCharts();
      } catch (e) {
        console.error('history:', e.message);
        setText($('history-note'), `history could not be loaded: ${e.message}`);
      } finally {
        compacting = false;
      }
    }

    // Most estimates held before the window is reloaded downsampled.
    const MAX_HELD = 4 * HISTORY_POINTS;
    let compacting = false;
    function compactIfLarge() {
      if (!compacting && state.estimates.size > MAX_HELD) {
        compacting = true;
        loadHistory(true);
      }
    }

    async function backfill(fromT, why) {
      setConnection('backfilling');
      try {
        const [history, lasers] = await Promise.all([
          tn.json(`${API}/estimates?engine=attitude&from=${fromT}&max_points=${BACKFILL_POINTS}`),
          tn.ndjson(`${API}/readings?sensor=laser&from=${fromT}&format=ndjson`, MAX_LASER),
        ]);
        for (const e of history.estimates) addEstimate(e);
        for (const r of lasers) addLaser(r);
        state.backfilled += history.estimates.length;
        setConnection('backfilled', `${why}: ${history.estimates.length} estimates backfilled`);
        scheduleRedraw();
        setTimeout(() => { if (state.connection === 'backfilled') setConnection('live'); }, 15000);
      } catch (e) {
        console.error('backfill:', e.message);
        setConnection('live');
      }
    }

    // ---- live socket --------------------------------------------------------
    function connect() {
      const live = tn.follow(API, {
        hello(m, isReconnect) {
          const resumeFrom = state.lastLiveT;
          if (m.latest && m.latest.attitude) addEstimate(m.latest.attitude);
          if (isReconnect && resumeFrom !== null) backfill(resumeFrom, 'reconnected');
          else setConnection('live');
          scheduleRedraw();
        },
        gap(m) {
          backfill(num(m.from_t) ? m.from_t : windowStart(), `fell behind (${m.missed} missed)`);
        },
        estimate(m) {
          if (m.engine !== 'attitude') return;
          addEstimate(m);
          state.lastLiveT = Math.max(state.lastLiveT || 0, m.t);
          scheduleRedraw();
        },
        closed() { setConnection('reconnecting'); },
      });
      Object.defineProperty(window.tunnelnav, 'socket', { get: () => live.socket });
    }

    // ---- readouts and status ------------------------------------------------
    function showReadouts() {
      const e = state.latest;
      if (!e) return;
      for (const name of ['pitch', 'roll']) {
        const value = e[`${name}_deg`], next = e[`${name}_pred_deg`];
        setText($(`${name}-value`), fixed(value, 3));
        setText($(`${name}-mm`), fixed(tn.mmPerM(value), 2));
        setText($(`${name}-pred`), fixed(next, 3));
        const sigma = e[`${name}_sigma_deg`];
        setText($(`${name}-sigma`), num(sigma) ? fixed(2 * sigma, 3) : '—');
        const change = next - value;
        let trend = '—';
        if (num(change)) {
          trend = Math.abs(change) < 0.0005 ? '► steady'
            : `${change > 0 ? '▲' : '▼'} ${change > 0 ? '+' : ''}${change.toFixed(4)}°`;
        }
        setText($(`${name}-trend`), trend);
      }
      setText($('est-time'), tn.timeOfDay(e.t));
      setText($('est-correction'), fixed(e.pitch_correction_deg, 4));
    }

    function showLaser() {
      const e = state.latest;
      const box = $('laser-status');
      let status = 'unknown', title = 'Laser', detail = 'waiting for data…';
      if (e) {
        const sinceEstimate = Math.max(0, tn.clock.now() - e.t);
        if (e.laser_ok) {
          status = 'ok';
          title = 'Laser OK';
          detail = `last sample ${tn.duration(e.laser_age_s + sinceEstimate)} ago; pitch and roll fuse laser and inclinometer`;
        } else if (num(e.laser_age_s)) {
          status = 'dropout';
          title = 'LASER DROPOUT';
          detail = `out for ${tn.duration(e.laser_age_s + sinceEstimate)}: pitch now rests on the inclinometer ` +
            'and the frozen ANFIS error model, roll on the inclinometer alone' +
            (num(e.pitch_sigma_deg) ? `; pitch is now good to ±${fixed(2 * e.pitch_sigma_deg, 3)}° (2σ)` : '');
        } else {
          status = 'none';
          title = 'No laser yet';
          detail = 'no laser sample received: pitch and roll rest on the inclinometer';
        }
        setText($('est-age'), tn.duration(sinceEstimate));
      }
      box.dataset.state = status;
      setText($('laser-title'), title);
      setText($('laser-detail'), detail);
    }

    // ---- start --------------------------------------------------------------
    async function start() {
      // The first status syncs the clock before the first window is computed.
      await tn.pollStatus(API, $('sensor-rows'));
      createCharts();
      tn.windowButtons('#windows', (seconds) => {
        state.windowS = seconds;
        drawTimeCharts();
        loadHistory();
      });
      await tn.runSection({
        root,
        charts,
        onTheme: createCharts,
        every: [
          [showLaser, 250],
          [scheduleRedraw, 1000], // the window slides even when nothing arrives
        ],
        load: async () => {
          await loadHistory();
          fetchModel();
          // The noise is re-estimated between trainings: refetch now and then.
          setInterval(fetchModel, 60000);
        },
        connect,
      });
    }

    start();
  },
});
