// The `fuzzy` engine's part of a machine page: the motion status and the
// expert's static degree, pitch, roll and heading with a compass rose, the
// magnetometer calibration, and over time: attitude, static degree (the
// static spans shaded) and the gyro bias estimates. History comes from the
// JSON API, then the `live` socket extends it (estimates arrive at the
// IMU's rate, about 100 Hz: the page keeps a thinned copy).
'use strict';

tn.registerEngine('fuzzy', {
  // The fleet card's rows from the newest estimate.
  card(f) {
    return [
      ['heading', `${tn.fixed(f.heading_deg, 1)}° · ${f.motion === 'static' ? 'static' : 'moving'} · compass ${f.mag_calibration}`],
      ['pitch / roll', `${tn.fixed(f.pitch_deg, 2)}° / ${tn.fixed(f.roll_deg, 2)}°`],
    ];
  },

  // The engine's section of a machine page.
  page() {
    const root = document.getElementById('machine');
    const MACHINE = root.dataset.machine;
    const API = `/api/v1/machines/${encodeURIComponent(MACHINE)}`;
    const $ = (id) => document.getElementById(id);
    const { fixed, setText, num, axis, line } = tn;

    const HISTORY_POINTS = 1500, BACKFILL_POINTS = 5000;
    const CHART_HEIGHT = 220, SMALL_HEIGHT = 160;
    // What the estimate's `compass` state says to the operator.
    const COMPASS_STATES = {
      believed: 'believed',
      raw: 'uncalibrated, holding the heading',
      collecting: 'not used: collecting directions',
      disturbed: 'not used: field disturbed',
      gated: 'not used: disagrees with the gyros',
      absent: 'not used: no recent reading',
    };
    const CALIBRATION_TEXT = {
      collecting: 'collecting directions: turn the vehicle through 90° or more',
      arc: 'calibrated from a partial turn with the gyros (provisional until a full turn)',
      raw: 'the raw field is consistent in every direction seen: used as it is (factory-calibrated)',
      planar: 'calibrated in the horizontal plane (hard and soft iron)',
      ellipsoid: 'calibrated in 3-D (hard and soft iron)',
    };

    const state = {
      windowS: 900,
      points: new Map(), // t → thinned estimate
      latest: null,
      lastKeptT: null,
      lastLiveT: null,
      connection: 'connecting',
      backfilled: 0,
    };
    const charts = {};
    window.tunnelnavFuzzy = { state, charts };

    function windowStart() {
      return tn.clock.now() - state.windowS;
    }

    function slim(e) {
      const b = e.gyro_bias_dps || [0, 0, 0];
      return {
        t: e.t, still: e.motion === 'static', degree: e.static_degree,
        pitch: e.pitch_deg, roll: e.roll_deg, heading: e.heading_deg,
        bx: b[0], by: b[1], bz: b[2],
      };
    }

    // ---- data ---------------------------------------------------------------
    // Thinned to about 3000 per window, keeping every change of the motion
    // status so the shading stays exact.
    function addEstimate(e, thin) {
      if (!e || e.engine !== 'fuzzy' || !num(e.t)) return;
      if (!state.latest || e.t >= state.latest.t) state.latest = e;
      const last = state.lastKeptT === null ? null : state.points.get(state.lastKeptT);
      const still = e.motion === 'static';
      if (thin && last && e.t - last.t < state.windowS / 3000 && still === last.still) return;
      state.points.set(e.t, slim(e));
      if (state.lastKeptT === null || e.t > state.lastKeptT) state.lastKeptT = e.t;
    }

    async function loadHistory() {
      setText($('fuzzy-history-note'), 'loading history…');
      try {
        const history = await tn.json(`${API}/estimates?engine=fuzzy&from=${windowStart()}&max_points=${HISTORY_POINTS}`);
        const end = history.estimates.length ? history.estimates[history.estimates.length - 1].t : Infinity;
        const newer = [...state.points.values()].filter((p) => p.t > end);
        state.points.clear();
        state.lastKeptT = null;
        for (const e of history.estimates) addEstimate(e, false);
        for (const p of newer) state.points.set(p.t, p);
        const how = history.downsampled ? ', downsampled by the server keeping each bucket’s pitch and roll extremes' : '';
        setText($('fuzzy-history-note'), history.estimates.length === 0
          ? 'no estimates in this window'
          : `history: ${history.estimates.length} estimates${how}; then live, thinned to ~3000 per window`);
        redraw();
      } catch (e) {
        console.error('history:', e.message);
        setText($('fuzzy-history-note'), `history could not be loaded: ${e.message}`);
      }
    }

    // ---- readouts -----------------------------------------------------------
    function showReadouts() {
      const e = state.latest;
      if (!e) return;
      setText($('f-heading'), fixed(e.heading_deg, 1));
      setText($('f-compass'), fixed(e.mag_heading_deg, 1));
      // 1σ of the heading and of the tilt (null before alignment).
      setText($('f-heading-sigma'), fixed(e.heading_sigma_deg, 1));
      setText($('f-tilt-sigma'), fixed(e.pitch_sigma_deg, 2));
      const compass = $('f-compass-state');
      compass.dataset.state = e.compass || 'unknown';
      setText(compass, e.compass
        ? `compass ${COMPASS_STATES[e.compass] || e.compass} since ${tn.timeOfDay(e.compass_since)}`
        : '—');
      setText($('f-pitch'), fixed(e.pitch_deg, 2));
      setText($('f-pitch-mm'), fixed(tn.mmPerM(e.pitch_deg), 1));
      setText($('f-roll'), fixed(e.roll_deg, 2));
      setText($('f-degree'), fixed(100 * e.static_degree, 0));
      setText($('f-time'), tn.timeOfDay(e.t));
      const bias = e.gyro_bias_dps || [];
      ['x', 'y', 'z'].forEach((axisName, i) => setText($(`f-bias-${axisName}`), fixed(bias[i], 4)));
      const sigma = e.gyro_bias_sigma_dps;
      setText($('f-bias-sigma'), sigma ? fixed(Math.max(...sigma), 4) : '—');
      $('f-disturbed').hidden = !e.mag_disturbed;
      setText($('f-accel-dev'), fixed(e.accel_dev_mps2, 3));
      setText($('f-accel-activity'), fixed(e.accel_activity_mps2, 3));
      setText($('f-gyro-activity'), fixed(e.gyro_activity_dps, 2));

      const box = $('fz-status');
      const status = !e.aligned ? 'aligning' : e.motion;
      box.dataset.state = status;
      setText($('fz-title'), { aligning: 'ALIGNING', static: 'STATIC', moving: 'MOVING' }[status] || '—');
      setText($('fz-detail'), !e.aligned
        ? 'waiting for a quiet moment to level and to fix the gyro bias'
        : e.motion === 'static'
          ? 'tilt from the accelerometers, heading from the compass, gyro bias re-estimated'
          : 'gyros integrated (bias-compensated)');

      const calibration = e.mag_calibration;
      const badge = $('f-calibration');
      setText(badge, calibration || '—');
      badge.className = `badge ${calibration === 'collecting' ? 'warn' : 'ok'}`;
      setText($('f-calibration-detail'), CALIBRATION_TEXT[calibration] || '—');
      setText($('f-coverage'), fixed(e.mag_coverage_deg, 0));
      setText($('f-fit'), num(e.mag_fit_rms) ? fixed(100 * e.mag_fit_rms, 2) : '—');
      drawCompass(e);
    }

    // A compass rose: the fused heading as the needle, the compass alone as
    // a hollow marker.
    function drawCompass(e) {
      const canvas = $('compass-canvas');
      const ctx = canvas.getContext('2d');
      const ratio = window.devicePixelRatio || 1;
      const size = canvas.clientWidth || 220;
      if (canvas.width !== Math.round(size * ratio)) { canvas.width = Math.round(size * ratio); canvas.height = Math.round(size * ratio); }
      ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
      ctx.clearRect(0, 0, size, size);
      const c = size / 2, r = size / 2 - 18;
      ctx.strokeStyle = tn.css('--grid');
      ctx.lineWidth = 1;
      ctx.beginPath();
      ctx.arc(c, c, r, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.fillStyle = tn.css('--muted');
      ctx.font = '12px system-ui, sans-serif';
      ctx.textAlign = 'center';
      ctx.textBaseline = 'middle';
      for (let d = 0; d < 360; d += 10) {
        const a = (d - 90) * Math.PI / 180;
        const inner = d % 90 === 0 ? r - 12 : d % 30 === 0 ? r - 8 : r - 4;
        ctx.beginPath();
        ctx.moveTo(c + inner * Math.cos(a), c + inner * Math.sin(a));
        ctx.lineTo(c + r * Math.cos(a), c + r * Math.sin(a));
        ctx.stroke();
        if (d % 90 === 0) ctx.fillText('NESW'[d / 90], c + (r + 10) * Math.cos(a), c + (r + 10) * Math.sin(a));
      }
      const needle = (deg, color, hollow) => {
        const a = (deg - 90) * Math.PI / 180;
        const tip = [c + (r - 14) * Math.cos(a), c + (r - 14) * Math.sin(a)];
        if (hollow) {
          ctx.strokeStyle = color;
          ctx.lineWidth = 2;
          ctx.beginPath();
          ctx.arc(tip[0], tip[1], 6, 0, 2 * Math.PI);
          ctx.stroke();
          return;
        }
        const side = (s) => [c + 7 * Math.cos(a + s * Math.PI / 2), c + 7 * Math.sin(a + s * Math.PI / 2)];
        ctx.fillStyle = color;
        ctx.beginPath();
        ctx.moveTo(...tip);
        ctx.lineTo(...side(1));
        ctx.lineTo(c - 20 * Math.cos(a), c - 20 * Math.sin(a));
        ctx.lineTo(...side(-1));
        ctx.closePath();
        ctx.fill();
      };
      if (num(e.mag_heading_deg)) needle(e.mag_heading_deg, tn.css('--laser'), true);
      if (num(e.heading_deg)) needle(e.heading_deg, tn.css('--fused'), false);
    }

    // ---- charts -------------------------------------------------------------
    const shadeStatic = tn.shadeSpans(() => [...state.points.values()].sort((a, b) => a.t - b.t), (p) => p.still);

    function timeRange(u, lo, hi) {
      return [windowStart(), Math.max(tn.clock.now(), hi || 0)];
    }

    const CHARTS = {
      attitude: CHART_HEIGHT,
      degree: SMALL_HEIGHT,
      bias: SMALL_HEIGHT,
    };

    function createCharts() {
      for (const c of Object.values(charts)) c.destroy();
      for (const k of Object.keys(charts)) delete charts[k];
      for (const name of Object.keys(CHARTS)) $(`${name}-chart`).textContent = '';
      const base = (name) => ({
        width: $(`${name}-chart`).clientWidth || 800,
        height: CHARTS[name],
        cursor: { drag: { x: false, y: false } },
        hooks: { drawClear: [shadeStatic] },
      });
      charts.attitude = new uPlot(Object.assign(base('attitude'), {
        scales: { x: { time: true, range: timeRange }, deg: {}, heading: { range: [0, 360] } },
        series: [{}, line('pitch', tn.css('--fused'), '°', 2, { scale: 'deg' }),
          line('roll', tn.css('--mf'), '°', 2, { scale: 'deg' }),
          line('heading', tn.css('--laser'), '°', 1, { scale: 'heading', dash: [6, 3] })],
        axes: [axis(), axis({ scale: 'deg', label: 'pitch, roll (°)', size: 60 }),
          axis({ scale: 'heading', side: 1, label: 'heading (°)', grid: { show: false }, size: 56 })],
      }), [[], [], [], []], $('attitude-chart'));
      charts.degree = new uPlot(Object.assign(base('degree'), {
        scales: { x: { time: true, range: timeRange }, y: { range: [0, 1] } },
        series: [{}, line('static degree', tn.css('--pred'), '', 2)],
        axes: [axis(), axis({ label: 'static degree', size: 60 })],
      }), [[], []], $('degree-chart'));
      charts.bias = new uPlot(Object.assign(base('bias'), {
        scales: { x: { time: true, range: timeRange } },
        series: [{}, line('bias x', tn.css('--fused'), '°/s', 4), line('bias y', tn.css('--mf'), '°/s', 4),
          line('bias z', tn.css('--laser'), '°/s', 4, { dash: [6, 3] })],
        axes: [axis(), axis({ label: 'gyro bias (°/s)', size: 64 })],
      }), [[], [], [], []], $('bias-chart'));
      redraw();
    }

    function drawCharts() {
      const from = windowStart();
      for (const [t] of state.points) if (t < from) state.points.delete(t);
      const points = [...state.points.values()].sort((a, b) => a.t - b.t);
      const ts = points.map((p) => p.t);
      charts.attitude.setData([ts, points.map((p) => p.pitch), points.map((p) => p.roll), points.map((p) => p.heading)]);
      charts.degree.setData([ts, points.map((p) => p.degree)]);
      charts.bias.setData([ts, points.map((p) => p.bx), points.map((p) => p.by), points.map((p) => p.bz)]);
    }

    const redraw = tn.debounce(() => {
      showReadouts();
      if (charts.attitude) drawCharts();
    }, 200);

    // ---- live ---------------------------------------------------------------
    function connect() {
      const live = tn.followEngine(API, 'fuzzy', { state, add: addEstimate, redraw, windowStart }, BACKFILL_POINTS);
      Object.defineProperty(window.tunnelnavFuzzy, 'socket', { get: () => live.socket });
    }

    async function start() {
      await tn.pollStatus(API, $('sensor-rows'));
      createCharts();
      tn.windowButtons('#fuzzy-windows', (seconds) => {
        state.windowS = seconds;
        loadHistory();
      });
      await tn.runSection({
        root,
        charts,
        onTheme: createCharts,
        resized: () => { if (state.latest) drawCompass(state.latest); },
        every: [
          [redraw, 1000], // the window slides even when nothing arrives
          [() => { if (state.points.size > 4 * HISTORY_POINTS + 3000) loadHistory(); }, 5000],
        ],
        load: loadHistory,
        connect,
      });
    }

    start();
  },
});
