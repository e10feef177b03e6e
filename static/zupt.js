// The `zupt` engine's part of a machine page: the zero-velocity state and
// detector statistics, distance, speed, attitude and heading, the drive in
// plan and profile, distance and speed over time with the zero-velocity
// periods shaded, and the filter's position uncertainty. History comes
// from the JSON API, then the `live` socket extends it (estimates arrive at
// the IMU's rate, about 100 Hz: the page keeps a thinned copy).
'use strict';

tn.registerEngine('zupt', {
  // The fleet card's rows from the newest estimate.
  card(z) {
    return [
      ['distance', `${tn.fixed(z.distance_m, 2)} m · ${z.zv ? 'standing still' : 'moving'}`],
      ['heading', `${tn.fixed(z.yaw_deg, 2)}° · pitch ${tn.fixed(z.pitch_deg, 3)}°`],
    ];
  },

  // The engine's section of a machine page.
  page() {
    const root = document.getElementById('machine');
    const MACHINE = root.dataset.machine;
    const API = `/api/v1/machines/${encodeURIComponent(MACHINE)}`;
    const $ = (id) => document.getElementById(id);
    const { fixed, setText, num, axis, line } = tn;

    const HISTORY_POINTS = 1500, TRACK_POINTS = 2000, BACKFILL_POINTS = 5000;
    const CHART_HEIGHT = 240, SIGMA_HEIGHT = 160;
    const TESTS = ['mv', 'are', 'shoe', 'mag'];

    const state = {
      windowS: 900,
      points: new Map(), // t → thinned estimate, for the time charts
      track: [], // the whole drive, thinned: {t, n, e, d, h}
      latest: null,
      lastKeptT: null,
      lastLiveT: null,
      lastStillT: null, // newest estimate with zero velocity
      connection: 'connecting',
      backfilled: 0,
    };
    const charts = {};
    window.tunnelnavZupt = { state, charts };

    function windowStart() {
      return tn.clock.now() - state.windowS;
    }

    // The few numbers the charts need from one estimate.
    function slim(e) {
      const v = e.velocity_mps || [0, 0, 0];
      const p = e.position_m || [0, 0, 0];
      const s = e.position_sigma_m || [0, 0, 0];
      return {
        t: e.t, zv: !!e.zv, distance: e.distance_m, speed: Math.hypot(v[0], v[1], v[2]) * 1000,
        n: p[0], e: p[1], d: p[2], h: num(e.height_m) ? e.height_m : -p[2],
        sn: s[0] * 1000, se: s[1] * 1000, sd: s[2] * 1000,
      };
    }

    // ---- data ---------------------------------------------------------------
    // Live estimates are thinned to about 3000 per window, keeping every
    // change of the zero-velocity decision so the shading stays exact.
    function addEstimate(e, thin) {
      if (!e || e.engine !== 'zupt' || !num(e.t)) return;
      if (!state.latest || e.t >= state.latest.t) state.latest = e;
      if (e.zv && (state.lastStillT === null || e.t > state.lastStillT)) state.lastStillT = e.t;
      const last = state.lastKeptT === null ? null : state.points.get(state.lastKeptT);
      const spacing = state.windowS / 3000;
      if (thin && last && e.t - last.t < spacing && !!e.zv === last.zv) return;
      const point = slim(e);
      state.points.set(e.t, point);
      if (state.lastKeptT === null || e.t > state.lastKeptT) state.lastKeptT = e.t;
      const end = state.track[state.track.length - 1];
      if (e.aligned && (!end || (e.t > end.t && (Math.hypot(point.n - end.n, point.e - end.e) > 0.02 || e.t - end.t > 30)))) {
        state.track.push(point);
      }
    }

    async function loadHistory() {
      setText($('zupt-history-note'), 'loading history…');
      try {
        const from = windowStart();
        const history = await tn.json(`${API}/estimates?engine=zupt&from=${from}&max_points=${HISTORY_POINTS}`);
        const newer = [...state.points.values()].filter((p) => history.estimates.length && p.t > history.estimates[history.estimates.length - 1].t);
        state.points.clear();
        state.lastKeptT = null;
        for (const e of history.estimates) addEstimate(e, false);
        for (const p of newer) state.points.set(p.t, p);
        const how = history.downsampled ? ', downsampled by the server keeping each bucket’s extremes' : '';
        setText($('zupt-history-note'), history.estimates.length === 0
          ? 'no estimates in this window'
          : `history: ${history.estimates.length} estimates${how}; then live, thinned to ~3000 per window`);
        redraw();
      } catch (e) {
        console.error('history:', e.message);
        setText($('zupt-history-note'), `history could not be loaded: ${e.message}`);
      }
    }

    // The whole drive for plan and profile, downsampled by the server.
    async function loadTrack() {
      try {
        const history = await tn.json(`${API}/estimates?engine=zupt&from=0&max_points=${TRACK_POINTS}`);
        const live = state.track.filter((p) => history.estimates.length && p.t > history.estimates[history.estimates.length - 1].t);
        state.track = history.estimates.filter((e) => e.aligned).map(slim).concat(live);
        drawXY();
      } catch (e) {
        console.error('track:', e.message);
      }
    }

    // ---- readouts -----------------------------------------------------------
    function showReadouts() {
      const e = state.latest;
      if (!e) return;
      const p = slim(e);
      setText($('z-distance'), fixed(e.distance_m, 3));
      setText($('z-speed'), fixed(p.speed, 1));
      setText($('z-odometer'), fixed(e.odometer_m, 3));
      setText($('z-yaw'), fixed(e.yaw_deg, 2));
      setText($('z-yaw-sigma'), fixed(e.yaw_sigma_deg, 3));
      setText($('z-pitch'), fixed(e.pitch_deg, 3));
      setText($('z-pitch-mm'), fixed(tn.mmPerM(e.pitch_deg), 2));
      setText($('z-roll'), fixed(e.roll_deg, 3));
      setText($('z-north'), fixed(p.n, 3));
      setText($('z-east'), fixed(p.e, 3));
      setText($('z-height'), fixed(p.h, 4));
      setText($('z-sn'), fixed(p.sn, 1));
      setText($('z-se'), fixed(p.se, 1));
      setText($('z-sd'), fixed(p.sd, 1));
      setText($('z-time'), tn.timeOfDay(e.t));

      const box = $('zv-status');
      let status, title, detail;
      if (!e.aligned) {
        status = 'aligning';
        title = 'ALIGNING';
        detail = 'waiting for the machine to stand still: the first still window levels the INS';
      } else if (e.zv) {
        status = 'still';
        title = 'STANDING STILL';
        detail = 'zero-velocity updates are correcting the INS';
      } else {
        status = 'moving';
        title = 'MOVING';
        const since = state.lastStillT === null ? null : e.t - state.lastStillT;
        detail = since === null ? 'free inertial navigation'
          : `free inertial navigation for ${tn.duration(since)} since the last rest`;
      }
      box.dataset.state = status;
      setText($('zv-title'), title);
      setText($('zv-detail'), detail);

      for (const test of TESTS) {
        const ratio = e[`${test}_ratio`];
        // Log scale from 0.01 γ (empty) to 100 γ (full); γ sits in the middle.
        const share = num(ratio) && ratio > 0 ? Math.min(1, Math.max(0, (Math.log10(ratio) + 2) / 4)) : (ratio === 0 ? 0 : 1);
        const bar = $(`bar-${test}`);
        bar.style.width = `${(share * 100).toFixed(1)}%`;
        bar.dataset.still = String(num(ratio) && ratio < 1);
        setText($(`ratio-${test}`), num(ratio) ? (ratio < 10 ? ratio.toFixed(2) : ratio.toFixed(0)) : '—');
        setText($(`verdict-${test}`), num(ratio) ? (ratio < 1 ? 'still' : 'moving') : '—');
      }
      const aligned = $('z-aligned');
      setText(aligned, e.aligned ? 'aligned' : 'not aligned yet');
      aligned.className = `badge ${e.aligned ? 'ok' : 'warn'}`;
    }

    // ---- charts -------------------------------------------------------------
    // Shades the zero-velocity spans of the held points.
    const shadeStill = tn.shadeSpans(() => [...state.points.values()].sort((a, b) => a.t - b.t), (p) => p.zv);

    function timeRange(u, lo, hi) {
      return [windowStart(), Math.max(tn.clock.now(), hi || 0)];
    }

    function createCharts() {
      for (const c of Object.values(charts)) c.destroy();
      for (const k of Object.keys(charts)) delete charts[k];
      $('distance-chart').textContent = '';
      $('sigma-chart').textContent = '';
      charts.distance = new uPlot({
        width: $('distance-chart').clientWidth || 800,
        height: CHART_HEIGHT,
        scales: { x: { time: true, range: timeRange }, mps: {} },
        series: [{}, line('distance', tn.css('--fused'), 'm', 3, { scale: 'm' }),
          line('speed (with vibration)', tn.css('--pred'), 'mm/s', 1, { scale: 'mps' })],
        axes: [axis(), axis({ scale: 'm', label: 'distance (m)', size: 64 }),
          axis({ scale: 'mps', side: 1, label: 'speed (mm/s)', grid: { show: false }, size: 60 })],
        hooks: { drawClear: [shadeStill] },
        cursor: { drag: { x: false, y: false } },
      }, [[], [], []], $('distance-chart'));
      charts.sigma = new uPlot({
        width: $('sigma-chart').clientWidth || 800,
        height: SIGMA_HEIGHT,
        scales: { x: { time: true, range: timeRange } },
        series: [{}, line('σ north', tn.css('--fused'), 'mm', 1), line('σ east', tn.css('--laser'), 'mm', 1, { dash: [6, 3] }),
          line('σ height', tn.css('--mf'), 'mm', 1)],
        axes: [axis(), axis({ label: 'position 1σ (mm)', size: 64 })],
        cursor: { drag: { x: false, y: false } },
      }, [[], [], [], []], $('sigma-chart'));
      redraw();
    }

    function drawTimeCharts() {
      const from = windowStart();
      for (const [t] of state.points) if (t < from) state.points.delete(t);
      const points = [...state.points.values()].sort((a, b) => a.t - b.t);
      const ts = points.map((p) => p.t);
      charts.distance.setData([ts, points.map((p) => p.distance), points.map((p) => p.speed)]);
      charts.sigma.setData([ts, points.map((p) => p.sn), points.map((p) => p.se), points.map((p) => p.sd)]);
    }

    // A polyline of [x, y] on a canvas with labelled bounds; `equal` keeps
    // one metre the same length on both axes.
    function drawCanvas(canvas, xy, options) {
      const ctx = canvas.getContext('2d');
      const ratio = window.devicePixelRatio || 1;
      const width = canvas.clientWidth || 600, height = canvas.clientHeight || 360;
      if (canvas.width !== Math.round(width * ratio)) { canvas.width = Math.round(width * ratio); canvas.height = Math.round(height * ratio); }
      ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
      ctx.clearRect(0, 0, width, height);
      const pad = { left: 64, right: 16, top: 14, bottom: 36 };
      const w = width - pad.left - pad.right, h = height - pad.top - pad.bottom;
      ctx.font = '12px system-ui, sans-serif';
      ctx.fillStyle = tn.css('--muted');
      if (xy.length === 0) { ctx.fillText('no position yet', pad.left, pad.top + 20); return; }
      let [x0, x1, y0, y1] = [Infinity, -Infinity, Infinity, -Infinity];
      for (const [x, y] of xy) { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); }
      const grow = (lo, hi, min) => { const mid = (lo + hi) / 2, half = Math.max((hi - lo) / 2 * 1.1, min); return [mid - half, mid + half]; };
      [x0, x1] = grow(x0, x1, options.minSpan);
      [y0, y1] = grow(y0, y1, options.minSpanY || options.minSpan);
      if (options.equal) {
        const scale = Math.max((x1 - x0) / w, (y1 - y0) / h);
        [x0, x1] = grow(x0, x1, scale * w / 2);
        [y0, y1] = grow(y0, y1, scale * h / 2);
      }
      const px = (x) => pad.left + (x - x0) / (x1 - x0) * w;
      const py = (y) => pad.top + (1 - (y - y0) / (y1 - y0)) * h;
      ctx.strokeStyle = tn.css('--grid');
      ctx.strokeRect(pad.left, pad.top, w, h);
      ctx.fillText(`${y1.toFixed(3)}`, 4, pad.top + 10);
      ctx.fillText(`${y0.toFixed(3)}`, 4, pad.top + h);
      ctx.fillText(`${x0.toFixed(3)}`, pad.left, height - 20);
      const right = `${x1.toFixed(3)}`;
      ctx.fillText(right, pad.left + w - ctx.measureText(right).width, height - 20);
      ctx.fillText(options.xLabel, pad.left + w / 2 - 30, height - 6);
      ctx.save();
      ctx.translate(14, pad.top + h / 2 + 30);
      ctx.rotate(-Math.PI / 2);
      ctx.fillText(options.yLabel, 0, 0);
      ctx.restore();
      ctx.strokeStyle = tn.css('--fused');
      ctx.lineWidth = 2;
      ctx.beginPath();
      xy.forEach(([x, y], i) => (i === 0 ? ctx.moveTo(px(x), py(y)) : ctx.lineTo(px(x), py(y))));
      ctx.stroke();
      const [cx, cy] = xy[xy.length - 1];
      if (options.ellipse) {
        const [sx, sy] = options.ellipse;
        ctx.strokeStyle = tn.css('--pred');
        ctx.beginPath();
        ctx.ellipse(px(cx), py(cy), Math.max(2, Math.abs(px(cx + 2 * sx) - px(cx))), Math.max(2, Math.abs(py(cy + 2 * sy) - py(cy))), 0, 0, 2 * Math.PI);
        ctx.stroke();
      }
      ctx.fillStyle = tn.css('--marker');
      ctx.beginPath();
      ctx.arc(px(cx), py(cy), 5, 0, 2 * Math.PI);
      ctx.fill();
    }

    function drawXY() {
      const track = state.track;
      const last = track[track.length - 1];
      drawCanvas($('plan-canvas'), track.map((p) => [p.e, p.n]), {
        xLabel: 'east (m)', yLabel: 'north (m)', equal: true, minSpan: 0.5,
        ellipse: last ? [last.se / 1000, last.sn / 1000] : null,
      });
      drawCanvas($('profile-canvas'), track.map((p) => [p.distance, p.h]), {
        xLabel: 'distance (m)', yLabel: 'height (m)', minSpan: 0.5, minSpanY: 0.05,
      });
      setText($('track-note'), last
        ? `${track.length} points over ${fixed(last.distance, 2)} m; now ${fixed(last.n, 3)} m N, ${fixed(last.e, 3)} m E, height ${fixed(last.h, 4)} m`
        : 'no aligned position yet');
    }

    const redraw = tn.debounce(() => {
      showReadouts();
      if (charts.distance) drawTimeCharts();
      drawXY();
    }, 200);

    // ---- live ---------------------------------------------------------------
    function connect() {
      const live = tn.followEngine(API, 'zupt', { state, add: addEstimate, redraw, windowStart }, BACKFILL_POINTS);
      Object.defineProperty(window.tunnelnavZupt, 'socket', { get: () => live.socket });
    }

    async function start() {
      await tn.pollStatus(API, $('sensor-rows'));
      createCharts();
      tn.windowButtons('#zupt-windows', (seconds) => {
        state.windowS = seconds;
        loadHistory();
      });
      await tn.runSection({
        root,
        charts,
        onTheme: createCharts,
        resized: drawXY,
        every: [
          [redraw, 1000], // the window slides even when nothing arrives
          [() => { if (state.points.size > 4 * HISTORY_POINTS + 3000) loadHistory(); }, 5000],
          [loadTrack, 60000],
        ],
        load: () => Promise.all([loadHistory(), loadTrack()]),
        connect,
      });
    }

    start();
  },
});
