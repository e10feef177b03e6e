// The `dta` stage's part of a machine page: the machine against the
// designed tunnel axis. The head/tail target (the cross-section with the
// tolerance boxes, the front and rear marks and the tendency), the four
// deviations as big readouts coloured by their status, the deviations
// against station over the whole drive, and plan and profile with the
// design axis and the driven track. The drive comes from the history API
// (downsampled by the server), then the `live` socket extends it.
//
// Signs as the stage gives them: horizontal + right of the axis looking
// along increasing station, vertical + above the design height.
//
// A machine that declares its steering also gets the correction curve
// (`GET .../steering`, fetched for each newest dta estimate): on the
// target (where the front should be after each step, the next one
// ringed), dashed on the deviation charts, and as a table per step.
'use strict';

tn.registerEngine('dta', {
  // The fleet card's rows from the newest estimate; the status word is
  // coloured (fleet.js puts the text in as HTML: only numbers and fixed
  // words go in).
  card(d) {
    const { signedMm, chainage, STATUS_WORD } = tn.engines.dta;
    const f = d.front || {}, r = d.rear || {};
    const status = STATUS_WORD[d.status] ? d.status : 'none';
    return [
      ['DTA front', `H ${signedMm(f.horizontal_mm)} · V ${signedMm(f.vertical_mm)} mm`],
      ['DTA rear', `H ${signedMm(r.horizontal_mm)} · V ${signedMm(r.vertical_mm)} mm`],
      ['axis', `<span class="dta-flag" data-status="${status}">${STATUS_WORD[status]}</span> at ${chainage(d.station_m)}`],
    ];
  },

  STATUS_WORD: { ok: 'OK', warn: 'WARN', alarm: 'ALARM', unknown: 'UNKNOWN', none: 'no tolerances' },

  // Millimetres, rounded, signed with a true minus: "+70", "−12", "0".
  signedMm(v) {
    if (!tn.num(v)) return '—';
    const r = Math.round(v);
    if (r === 0) return '0';
    return `${r > 0 ? '+' : '\u2212'}${Math.abs(r)}`;
  },

  // A station as chainage, kilometres + metres: 1234.5 → "1+234.500"
  // (common.js's, as the reports write it).
  chainage(s, digits = 3) {
    return tn.chainage(s, digits);
  },

  // One deviation against its limits: ok, warn, alarm (over the limit, as
  // the stage grades), or none without limits.
  grade(v, limits) {
    if (!tn.num(v) || !limits.warn || !limits.alarm) return 'none';
    const a = Math.abs(v);
    return a > limits.alarm ? 'alarm' : a > limits.warn ? 'warn' : 'ok';
  },

  // The stage's section of a machine page.
  page() {
    const root = document.getElementById('machine');
    const section = document.getElementById('dta');
    const MACHINE = root.dataset.machine;
    const API = `/api/v1/machines/${encodeURIComponent(MACHINE)}`;
    const $ = (id) => document.getElementById(id);
    const { fixed, setText, num, axis, line, css } = tn;
    const { signedMm, chainage, grade } = tn.engines.dta;

    const limit = (key) => {
      const v = parseFloat(section.dataset[key]);
      return isFinite(v) && v > 0 ? v : null;
    };
    const LIMITS = {
      h: { warn: limit('warnH'), alarm: limit('alarmH') },
      v: { warn: limit('warnV'), alarm: limit('alarmV') },
    };
    const LIMITED = !!(LIMITS.h.alarm && LIMITS.v.alarm);
    const LENGTH_M = parseFloat(section.dataset.lengthM) || 0;
    // The tendency arrow: where the front goes over the next machine length
    // (10 m without a geometry) if the machine keeps its attitude.
    const AHEAD_M = LENGTH_M > 0 ? LENGTH_M : 10;
    const DRIVE_POINTS = 4000, BACKFILL_POINTS = 5000;
    // The drive keeps the newest estimate per 10 cm of station: standing
    // still is one point, not thousands.
    const STATION_BUCKET_M = 0.1;
    const TRAIL = 16; // the front's last positions, faded, on the target
    const CHART_HEIGHT = 210;
    const POINTS = ['front', 'rear'], COMPONENTS = ['h', 'v'];
    const FIELD = { h: 'horizontal_mm', v: 'vertical_mm' };
    const BADGE_CLASS = { ok: 'ok', warn: 'warn', alarm: 'bad' };

    const state = {
      latest: null,
      drive: new Map(), // station bucket → {t, s, fs, fh, fv, rs, rh, rv}
      trail: [], // the front's newest positions: {t, h, v}
      axis: [], // the design axis sampled: {station_m, easting_m, northing_m, height_m}
      lastLiveT: null,
      connection: 'connecting',
      backfilled: 0,
      // The newest correction curve (`GET .../steering`) and the dta
      // estimate's time it was asked for.
      steering: null,
      steeringFor: null,
    };
    const STEER = $('dta-steer');
    const charts = {};
    // What the canvases drew last (CSS pixels) and how often: for the
    // browser test and anyone debugging in the console.
    const draws = { target: 0, plan: 0, profile: 0 };
    const marks = {};
    window.tunnelnavDta = { state, charts, draws, marks, limits: LIMITS };

    setText($('dta-ahead'), fixed(AHEAD_M, 1));

    // ---- data ---------------------------------------------------------------
    function slim(e) {
      return {
        t: e.t, s: e.station_m,
        fs: e.front.station_m, fh: e.front.horizontal_mm, fv: e.front.vertical_mm,
        rs: e.rear.station_m, rh: e.rear.horizontal_mm, rv: e.rear.vertical_mm,
      };
    }

    // A position too old (five of its own intervals, at least 30 s) or
    // lost is never shown as live: greyed and struck, with its age.
    const fresh = tn.freshness(30);
    let shownLive = null;
    function add(e) {
      if (!e || e.engine !== 'dta' || !num(e.t) || !num(e.station_m) || !e.front || !e.rear) return;
      fresh.judge('dta', e, e.t); // learns the interval between positions
      if (!state.latest || e.t >= state.latest.t) state.latest = e;
      const key = Math.round(e.station_m / STATION_BUCKET_M);
      const held = state.drive.get(key);
      if (!held || e.t >= held.t) state.drive.set(key, slim(e));
      const trail = state.trail;
      if (!trail.length || e.t > trail[trail.length - 1].t) {
        trail.push({ t: e.t, h: e.front.horizontal_mm, v: e.front.vertical_mm });
        if (trail.length > TRAIL) trail.shift();
      }
    }

    // The curve for the newest estimate, once per estimate; only the
    // newest request's answer is used.
    const fetchSteering = tn.latestOnly(
      async () => tn.json(`${API}/steering`),
      (curve) => {
        state.steering = curve;
        showSteering();
        drawTarget();
        drawStationCharts();
      },
      (e) => setText($('dta-steer-summary'), `the correction curve: ${e.message}`),
    );

    // At most once a second (a zupt machine's estimates come many a
    // second); a newer estimate meanwhile is asked for after it.
    let steeringAskedAt = 0, steeringLater = null;
    function refreshSteering() {
      if (!STEER || !state.latest || state.steeringFor === state.latest.t) return;
      const wait = steeringAskedAt + 1000 - Date.now();
      if (wait > 0) {
        if (!steeringLater) steeringLater = setTimeout(() => { steeringLater = null; refreshSteering(); }, wait);
        return;
      }
      steeringAskedAt = Date.now();
      state.steeringFor = state.latest.t;
      fetchSteering();
    }

    // The curve's points per step: {k, s, h, v, sh, sv, outside} (sh, sv:
    // the stroke differences over the step from that point; outside:
    // beyond a warn limit).
    function curvePoints() {
      const c = state.steering;
      if (!c || !c.feasible) return [];
      return c.horizontal.points.map((p, k) => ({
        k, s: p.station_m, h: p.deviation_mm, v: c.vertical.points[k].deviation_mm,
        sh: p.stroke_difference_mm, sv: c.vertical.points[k].stroke_difference_mm,
        outside: Boolean(p.outside_warn || c.vertical.points[k].outside_warn),
      }));
    }

    function showSteering() {
      const c = state.steering;
      const badge = $('dta-steer-status');
      const body = $('dta-steer-table').tBodies[0];
      if (!c) return;
      const one = (v) => (num(v) ? `${v > 0 ? '+' : v < 0 ? '\u2212' : ''}${Math.abs(v).toFixed(1)}` : '—');
      const groupsBox = $('dta-steer-groups-box');
      if (!c.feasible) {
        badge.dataset.status = 'alarm';
        badge.className = 'badge bad';
        setText(badge, 'no curve back within the radius');
        setText($('dta-steer-words'), 'no curve: steer by hand');
        setText($('dta-steer-summary'), c.reason || 'no curve back to the axis');
        body.replaceChildren();
        groupsBox.hidden = true;
        return;
      }
      const points = curvePoints();
      const outside = points.filter((p) => p.outside).length;
      badge.dataset.status = outside ? 'warn' : 'ok';
      badge.className = outside ? 'badge warn' : 'badge ok';
      setText(badge, outside ? `${c.steps} steps; ${outside} beyond the warn limit` : `${c.steps} steps to the axis`);
      setText($('dta-steer-words'), c.words || '');
      setText($('dta-steer-summary'), `${c.steps} steps (${fixed(c.length_m, 1)} m) from ${chainage(c.horizontal.points[0].station_m)}`
        + ` to ${chainage(c.horizontal.points[c.steps].station_m)}; ${c.replanned ? 'planned' : 'held'} at the estimate of ${tn.timeOfDay(c.t)}`);
      const cells = (texts) => {
        const row = document.createElement('tr');
        for (const text of texts) {
          const cell = document.createElement('td');
          cell.textContent = text;
          row.appendChild(cell);
        }
        return row;
      };
      const rows = points.slice(1).map((p) => {
        const from = points[p.k - 1];
        const row = cells([String(p.k), chainage(p.s), one(p.h), one(p.v), one(from.sh), one(from.sv),
          p.outside ? '\u26a0 beyond warn' : '']);
        if (p.outside) row.className = 'outside-warn';
        return row;
      });
      body.replaceChildren(...rows);
      const groups = c.groups || [];
      groupsBox.hidden = groups.length === 0;
      $('dta-steer-groups').tBodies[0].replaceChildren(...groups.map((g) => cells([
        g.name, fixed(g.angle_deg, 0), one(g.extension_difference_mm),
        num(g.target_stroke_mm) ? fixed(g.target_stroke_mm, 1) : '—'])));
    }

    async function loadDrive() {
      setText($('dta-drive-note'), 'loading the drive…');
      try {
        const history = await tn.json(`${API}/estimates?engine=dta&from=0&max_points=${DRIVE_POINTS}`);
        for (const e of history.estimates) add(e);
        state.downsampled = history.downsampled;
      } catch (e) {
        console.warn('dta history:', e.message);
        setText($('dta-drive-note'), `the drive could not be loaded: ${e.message}`);
      }
    }

    // The design axis, sampled every 5 m (coarser for very long axes,
    // which the server refuses at 5 m).
    async function loadAxis() {
      for (const step of [5, 50, 500]) {
        try {
          const body = await tn.json(`${API}/alignment/axis?step_m=${step}`);
          state.axis = body.points.slice().sort((a, b) => a.station_m - b.station_m);
          return;
        } catch (e) {
          console.warn('design axis:', e.message);
        }
      }
      setText($('dta-axis-note'), 'the design axis could not be loaded');
    }

    // The axis at station `s` (interpolated; extended straight beyond its
    // ends): position, design height and the unit direction (E, N).
    function axisAt(s) {
      const a = state.axis;
      if (a.length < 2 || !num(s)) return null;
      let lo = 0, hi = a.length - 1;
      while (hi - lo > 1) {
        const mid = (lo + hi) >> 1;
        if (a[mid].station_m <= s) lo = mid; else hi = mid;
      }
      const p = a[lo], q = a[hi];
      const ds = q.station_m - p.station_m || 1;
      const f = (s - p.station_m) / ds;
      const de = q.easting_m - p.easting_m, dn = q.northing_m - p.northing_m;
      const len = Math.hypot(de, dn) || 1;
      return {
        e: p.easting_m + f * de, n: p.northing_m + f * dn,
        h: p.height_m + f * (q.height_m - p.height_m),
        de: de / len, dn: dn / len,
      };
    }

    // A point `right_mm` right of the axis at station `s`, in plan: the
    // right-hand normal of the direction (sin A, cos A) is (cos A, −sin A).
    function planPoint(s, rightMm) {
      const a = axisAt(s);
      if (!a || !num(rightMm)) return null;
      const r = rightMm / 1000;
      return [a.e + a.dn * r, a.n - a.de * r];
    }

    // ---- readouts -----------------------------------------------------------
    function worst(e) {
      let out = null;
      for (const p of POINTS) {
        for (const c of COMPONENTS) {
          const v = e[p][FIELD[c]], lim = LIMITS[c];
          if (!num(v) || !lim.warn) continue;
          const ratio = Math.abs(v) / lim.warn;
          if (!out || ratio > out.ratio) out = { ratio, point: p, comp: c, v, status: grade(v, lim) };
        }
      }
      return out;
    }

    const judged = (e) => fresh.judge('dta', e, tn.clock.now());

    function showReadouts() {
      const e = state.latest;
      if (!e) return;
      const now = judged(e);
      shownLive = !now.notLive;
      for (const p of POINTS) {
        for (const c of COMPONENTS) {
          const v = e[p][FIELD[c]];
          setText($(`dta-${p}-${c}`), signedMm(v));
          const box = $(`dta-${p}-${c}-box`);
          const status = now.notLive ? 'stale' : grade(v, LIMITS[c]);
          if (box.dataset.status !== status) box.dataset.status = status;
          let dir = '';
          if (num(v) && Math.round(v) !== 0) dir = c === 'h' ? (v > 0 ? '▶' : '◀') : (v > 0 ? '▲' : '▼');
          setText($(`dta-${p}-${c}-dir`), dir);
          const word = c === 'h' ? (v > 0 ? 'right of' : 'left of') : (v > 0 ? 'above' : 'below');
          box.title = num(v) ? `${Math.abs(v).toFixed(1)} mm ${word} the axis` : '';
          // The source's own 1σ (INS positions carry one, laser ones not).
          const sigma = e[p][c === 'h' ? 'sigma_horizontal_mm' : 'sigma_vertical_mm'];
          setText($(`dta-${p}-${c}-sigma`), num(sigma) ? `± ${sigma.toFixed(sigma < 10 ? 1 : 0)} mm` : '');
        }
      }
      setText($('dta-chainage'), chainage(e.station_m));
      setText($('dta-station'), `${fixed(e.station_m, 3)} m`);
      setText($('dta-front-station'), chainage(e.front.station_m, 2));
      setText($('dta-rear-station'), chainage(e.rear.station_m, 2));
      const th = e.tendency_horizontal_mm_per_m, tv = e.tendency_vertical_mm_per_m;
      const signed = (v) => {
        if (!num(v)) return '—';
        const text = Math.abs(v).toFixed(1);
        return Number(text) === 0 ? text : `${v > 0 ? '+' : '\u2212'}${text}`;
      };
      setText($('dta-tend-h'), signed(th));
      setText($('dta-tend-v'), signed(tv));
      const steer = [];
      if (num(th) && Math.abs(th) >= 0.05) steer.push(`heading ${th > 0 ? 'right' : 'left'}`);
      if (num(tv) && Math.abs(tv) >= 0.05) steer.push(`heading ${tv > 0 ? 'up' : 'down'}`);
      setText($('dta-tend-words'), steer.length ? steer.join(' · ') : 'parallel to the axis');
      setText($('dta-source'), e.source === 'laser' ? 'laser (total station)' : e.source === 'zupt' ? 'inertial (zupt)' : String(e.source));
      setText($('dta-time'), tn.timeOfDay(e.t));
      showAge();
      setText($('dta-note'), `${LENGTH_M > 0 ? `front and rear ${fixed(LENGTH_M, 2)} m apart` : 'no machine length declared'}`
        + `; the arrow on the target is where the front goes over the next ${fixed(AHEAD_M, 1)} m if the machine keeps its attitude`);
    }

    // The badge: the deviation's grade, or NOT LIVE with its age (redrawn
    // every second, so the age said is the age now).
    function showBadge(e, now) {
      const badge = $('dta-status');
      let status = ['ok', 'warn', 'alarm', 'unknown'].includes(e.status) ? e.status : 'none';
      if (now.notLive) status = 'stale';
      // A position whose source cannot vouch for it (docs/protocol.md, "Integrity").
      const words = tn.integrityWords(e);
      const trust = words ? ` · position ${words}` : '';
      const w = worst(e);
      const where = w ? `${w.point} ${w.comp === 'h' ? 'horizontal' : 'vertical'} ${signedMm(w.v)} mm` : '';
      const text = {
        ok: 'OK · within tolerance',
        warn: `WARNING · ${where}`,
        alarm: `ALARM · ${where}`,
        unknown: 'UNKNOWN · the uncertainty reaches across a limit',
        none: 'no tolerances declared',
        stale: `NOT LIVE · ${tn.trustNote(e, now) || 'position not vouched for'}: not a current deviation`,
      }[status] + (status === 'stale' ? '' : trust);
      if (badge.dataset.status !== status) badge.dataset.status = status;
      badge.className = `badge dta-badge ${BADGE_CLASS[status] || ''}`;
      setText(badge, text);
    }

    function showAge() {
      const e = state.latest;
      if (!e) return;
      const now = judged(e);
      const age = $('dta-age');
      setText(age, `${tn.duration(tn.clock.now() - e.t)} ago`);
      age.classList.toggle('age-stale', now.stale);
      showBadge(e, now);
      // Gone stale (or fresh again) since drawn: redraw as such.
      if (shownLive !== null && shownLive === now.notLive) showReadouts();
    }

    // ---- canvases -----------------------------------------------------------
    function colours() {
      const names = ['panel', 'fg', 'muted', 'border', 'grid', 'ok', 'ok-bg', 'warn', 'warn-bg',
        'bad', 'bad-bg', 'fused', 'pred', 'curve'];
      const out = {};
      for (const n of names) out[n.replace('-bg', 'Bg')] = css(`--${n}`);
      return out;
    }

    // A canvas sized to its box at the device's pixel ratio, cleared;
    // drawing is in CSS pixels.
    function prepare(canvas) {
      const ratio = window.devicePixelRatio || 1;
      const width = canvas.clientWidth || canvas.width, height = canvas.clientHeight || canvas.height;
      const w = Math.round(width * ratio), h = Math.round(height * ratio);
      if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
      const ctx = canvas.getContext('2d');
      ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
      ctx.clearRect(0, 0, width, height);
      ctx.font = '12px system-ui, sans-serif';
      ctx.lineJoin = 'round';
      return { ctx, width, height };
    }

    // Round values from lo to hi, about `count` of them.
    function ticks(lo, hi, count) {
      const span = hi - lo;
      if (!(span > 0) || !(count > 0)) return [lo];
      const raw = span / count, mag = 10 ** Math.floor(Math.log10(raw));
      const step = [1, 2, 2.5, 5, 10].map((f) => f * mag).find((s) => s >= raw * 0.999);
      const out = [];
      for (let i = Math.ceil(lo / step - 1e-9); i * step <= hi + step * 1e-9; i++) out.push(i * step);
      return out;
    }

    // The smallest round number at least v.
    function roundUp(v) {
      const mag = 10 ** Math.floor(Math.log10(v));
      return [1, 1.5, 2, 2.5, 3, 4, 5, 6, 8, 10].map((f) => f * mag).find((x) => x >= v * 0.999);
    }

    // Half the target's width, mm: the alarm box with a margin, or the
    // deviations themselves without tolerances.
    function targetRange() {
      if (LIMITED) return roundUp(1.4 * Math.max(LIMITS.h.alarm, LIMITS.v.alarm));
      let most = 20;
      const e = state.latest;
      if (e) for (const p of POINTS) for (const c of COMPONENTS) if (num(e[p][FIELD[c]])) most = Math.max(most, Math.abs(e[p][FIELD[c]]) * 1.3);
      for (const q of state.trail) most = Math.max(most, Math.abs(q.h) * 1.3, Math.abs(q.v) * 1.3);
      return roundUp(most);
    }

    function arrowHead(ctx, x0, y0, x1, y1, size) {
      const a = Math.atan2(y1 - y0, x1 - x0);
      ctx.beginPath();
      ctx.moveTo(x1, y1);
      ctx.lineTo(x1 - size * Math.cos(a - 0.45), y1 - size * Math.sin(a - 0.45));
      ctx.lineTo(x1 - size * Math.cos(a + 0.45), y1 - size * Math.sin(a + 0.45));
      ctx.closePath();
      ctx.fill();
    }

    // The head/tail target: the cross-section looking ahead, equal mm
    // scales both ways; zones inside the warn box, to the alarm box and
    // beyond it; the rear (square) joined to the front (circle), the
    // tendency arrow ahead of the front, the front's last positions faded.
    // A mark beyond the drawn range sits on the edge, ringed, with an
    // arrow pointing out and its values.
    function drawTarget() {
      const canvas = $('dta-target');
      const { ctx, width, height } = prepare(canvas);
      draws.target += 1;
      const c = colours();
      const R = targetRange();
      const left = 46, top = 12;
      const side = Math.max(60, Math.min(width - left - 12, height - top - 40));
      const half = side / 2, cx = left + half, cy = top + half;
      const px = (h) => cx + (h / R) * half, py = (v) => cy - (v / R) * half;
      const rect = (h, v) => [px(-h), py(v), px(h) - px(-h), py(-v) - py(v)];
      marks.range = R;

      ctx.fillStyle = c.panel;
      ctx.fillRect(left, top, side, side);
      if (LIMITED) {
        ctx.globalAlpha = 0.6; // beyond the alarm box: a tint, not a wall of red
        ctx.fillStyle = c.badBg;
        ctx.fillRect(left, top, side, side);
        ctx.globalAlpha = 1;
        ctx.fillStyle = c.warnBg;
        ctx.fillRect(...rect(LIMITS.h.alarm, LIMITS.v.alarm));
        ctx.fillStyle = c.okBg;
        ctx.fillRect(...rect(LIMITS.h.warn, LIMITS.v.warn));
      }
      // Grid and scale, mm.
      const marksAt = ticks(-R, R, 6);
      ctx.strokeStyle = c.grid;
      ctx.lineWidth = 1;
      ctx.fillStyle = c.muted;
      ctx.textAlign = 'center';
      ctx.textBaseline = 'top';
      for (const m of marksAt) {
        ctx.beginPath();
        ctx.moveTo(Math.round(px(m)) + 0.5, top);
        ctx.lineTo(Math.round(px(m)) + 0.5, top + side);
        ctx.moveTo(left, Math.round(py(m)) + 0.5);
        ctx.lineTo(left + side, Math.round(py(m)) + 0.5);
        ctx.stroke();
        ctx.fillText(signedMm(m), px(m), top + side + 5);
      }
      ctx.textAlign = 'right';
      ctx.textBaseline = 'middle';
      for (const m of marksAt) ctx.fillText(signedMm(m), left - 6, py(m));
      ctx.textAlign = 'center';
      ctx.textBaseline = 'top';
      ctx.fillText('horizontal (mm)', cx, top + side + 21);
      // The axis.
      ctx.strokeStyle = c.muted;
      ctx.beginPath();
      ctx.moveTo(left, Math.round(cy) + 0.5);
      ctx.lineTo(left + side, Math.round(cy) + 0.5);
      ctx.moveTo(Math.round(cx) + 0.5, top);
      ctx.lineTo(Math.round(cx) + 0.5, top + side);
      ctx.stroke();
      ctx.font = '600 12px system-ui, sans-serif';
      ctx.textBaseline = 'bottom';
      ctx.textAlign = 'left';
      ctx.fillText('L', left + 5, cy - 3);
      ctx.fillText('up', cx + 5, top + 16);
      ctx.textAlign = 'right';
      ctx.fillText('R', left + side - 5, cy - 3);
      ctx.textBaseline = 'top';
      ctx.textAlign = 'left';
      ctx.fillText('down', cx + 5, top + side - 16);
      // The tolerance boxes, labelled at their top right corners.
      if (LIMITED) {
        for (const [lim, colour, dash, width] of [['alarm', c.bad, [], 2], ['warn', c.warn, [5, 3], 1.5]]) {
          const [x, y, w, h] = rect(LIMITS.h[lim], LIMITS.v[lim]);
          ctx.strokeStyle = colour;
          ctx.lineWidth = width;
          ctx.setLineDash(dash);
          ctx.strokeRect(x, y, w, h);
          ctx.setLineDash([]);
          ctx.fillStyle = colour;
          ctx.font = '600 11px system-ui, sans-serif';
          ctx.textAlign = 'right';
          ctx.textBaseline = 'top';
          ctx.fillText(`${lim} ±${LIMITS.h[lim]}/±${LIMITS.v[lim]}`, x + w - 4, y + 3);
        }
      }
      ctx.font = '12px system-ui, sans-serif';
      ctx.strokeStyle = c.border;
      ctx.lineWidth = 1;
      ctx.strokeRect(left + 0.5, top + 0.5, side - 1, side - 1);

      const e = state.latest;
      if (!e) {
        ctx.fillStyle = c.muted;
        ctx.textAlign = 'center';
        ctx.textBaseline = 'middle';
        ctx.fillText('no position yet', cx, cy + 24);
        marks.front = marks.rear = null;
        return;
      }
      const fh = e.front.horizontal_mm, fv = e.front.vertical_mm;
      const rh = e.rear.horizontal_mm, rv = e.rear.vertical_mm;
      const place = (h, v) => {
        const ch = Math.max(-R, Math.min(R, h)), cv = Math.max(-R, Math.min(R, v));
        return { x: px(ch), y: py(cv), clamped: ch !== h || cv !== v, h, v };
      };
      const front = place(fh, fv), rear = place(rh, rv);

      ctx.save();
      ctx.beginPath();
      ctx.rect(left, top, side, side);
      ctx.clip();
      // The front's last positions, older ones fainter.
      ctx.fillStyle = c.fused;
      state.trail.slice(0, -1).forEach((q, i, all) => {
        const p = place(q.h, q.v);
        ctx.globalAlpha = 0.12 + 0.35 * ((i + 1) / all.length);
        ctx.beginPath();
        ctx.arc(p.x, p.y, 3, 0, 2 * Math.PI);
        ctx.fill();
      });
      ctx.globalAlpha = 1;
      // The machine seen end-on: rear to front.
      ctx.strokeStyle = c.fg;
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(rear.x, rear.y);
      ctx.lineTo(front.x, front.y);
      ctx.stroke();
      // The tendency: the front over the next AHEAD_M.
      const th = e.tendency_horizontal_mm_per_m, tv = e.tendency_vertical_mm_per_m;
      if (num(th) && num(tv) && !front.clamped) {
        const tipX = px(fh + th * AHEAD_M), tipY = py(fv + tv * AHEAD_M);
        if (Math.hypot(tipX - front.x, tipY - front.y) > 10) {
          ctx.strokeStyle = c.fused;
          ctx.fillStyle = c.fused;
          ctx.lineWidth = 2;
          ctx.setLineDash([6, 4]);
          ctx.beginPath();
          ctx.moveTo(front.x, front.y);
          ctx.lineTo(tipX, tipY);
          ctx.stroke();
          ctx.setLineDash([]);
          arrowHead(ctx, front.x, front.y, tipX, tipY, 11);
        }
      }
      // The correction curve: where the front should be after each step,
      // back to the centre; the next step ringed.
      const curve = curvePoints();
      marks.next = null;
      if (curve.length > 1 && !front.clamped) {
        const at = curve.map((q) => place(q.h, q.v));
        ctx.strokeStyle = c.warn;
        ctx.fillStyle = c.warn;
        ctx.lineWidth = 1.5;
        ctx.setLineDash([2, 3]);
        ctx.beginPath();
        at.forEach((p, i) => (i ? ctx.lineTo(p.x, p.y) : ctx.moveTo(p.x, p.y)));
        ctx.stroke();
        ctx.setLineDash([]);
        for (const p of at.slice(2)) {
          ctx.beginPath();
          ctx.arc(p.x, p.y, 2, 0, 2 * Math.PI);
          ctx.fill();
        }
        const next = at[1];
        ctx.lineWidth = 2.5;
        ctx.beginPath();
        ctx.arc(next.x, next.y, 9, 0, 2 * Math.PI);
        ctx.stroke();
        ctx.font = '600 11px system-ui, sans-serif';
        ctx.textAlign = next.x > cx ? 'right' : 'left';
        ctx.textBaseline = 'middle';
        ctx.fillText('next', next.x + (next.x > cx ? -13 : 13), next.y);
        ctx.font = '12px system-ui, sans-serif';
        marks.next = { x: next.x, y: next.y, h: curve[1].h, v: curve[1].v };
      }
      ctx.restore();

      // The marks, drawn last so nothing covers them.
      const outside = (p, colour) => {
        if (!p.clamped) return;
        const a = Math.atan2(-(p.v - (cy - p.y) / half * R), p.h - (p.x - cx) / half * R);
        ctx.strokeStyle = colour;
        ctx.fillStyle = colour;
        ctx.lineWidth = 1.5;
        ctx.setLineDash([3, 2]);
        ctx.beginPath();
        ctx.arc(p.x, p.y, 13, 0, 2 * Math.PI);
        ctx.stroke();
        ctx.setLineDash([]);
        const x0 = p.x + 14 * Math.cos(a), y0 = p.y + 14 * Math.sin(a);
        arrowHead(ctx, p.x, p.y, x0 + 9 * Math.cos(a), y0 + 9 * Math.sin(a), 9);
        ctx.font = '600 11px system-ui, sans-serif';
        ctx.textAlign = p.x > cx ? 'right' : 'left';
        ctx.textBaseline = p.y > cy ? 'bottom' : 'top';
        const dx = p.x > cx ? -16 : 16, dy = p.y > cy ? -14 : 14;
        ctx.fillText(`${signedMm(p.h)} / ${signedMm(p.v)}`, p.x + dx, p.y + dy);
        ctx.font = '12px system-ui, sans-serif';
      };
      // The rear an open square, larger than the front's dot, so it shows
      // around it when the machine lies parallel to the axis.
      ctx.lineWidth = 5;
      ctx.strokeStyle = c.panel;
      ctx.strokeRect(rear.x - 9, rear.y - 9, 18, 18);
      ctx.lineWidth = 3;
      ctx.strokeStyle = c.pred;
      ctx.strokeRect(rear.x - 9, rear.y - 9, 18, 18);
      outside(rear, c.pred);
      ctx.lineWidth = 2;
      ctx.strokeStyle = c.panel;
      ctx.fillStyle = c.fused;
      ctx.beginPath();
      ctx.arc(front.x, front.y, 7.5, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
      outside(front, c.fused);
      marks.front = { x: front.x, y: front.y, clamped: front.clamped };
      marks.rear = { x: rear.x, y: rear.y, clamped: rear.clamped };
    }

    // Axes on a prepared canvas for the box [x0, x1] × [y0, y1]; `equal`
    // keeps a metre the same length both ways. Returns the mapping.
    function frame(ctx, width, height, box, o, c) {
      const pad = { left: 66, right: 14, top: 12, bottom: 40 };
      const w = width - pad.left - pad.right, h = height - pad.top - pad.bottom;
      let [x0, x1, y0, y1] = box;
      if (o.equal) {
        const scale = Math.max((x1 - x0) / w, (y1 - y0) / h);
        const xm = (x0 + x1) / 2, ym = (y0 + y1) / 2;
        [x0, x1, y0, y1] = [xm - scale * w / 2, xm + scale * w / 2, ym - scale * h / 2, ym + scale * h / 2];
      }
      const px = (x) => pad.left + ((x - x0) / (x1 - x0)) * w;
      const py = (y) => pad.top + (1 - (y - y0) / (y1 - y0)) * h;
      ctx.strokeStyle = c.grid;
      ctx.fillStyle = c.muted;
      ctx.lineWidth = 1;
      ctx.textAlign = 'center';
      ctx.textBaseline = 'top';
      for (const x of ticks(x0, x1, Math.max(2, w / 110))) {
        ctx.beginPath();
        ctx.moveTo(Math.round(px(x)) + 0.5, pad.top);
        ctx.lineTo(Math.round(px(x)) + 0.5, pad.top + h);
        ctx.stroke();
        ctx.fillText(o.xFormat(x), px(x), pad.top + h + 5);
      }
      ctx.textAlign = 'right';
      ctx.textBaseline = 'middle';
      for (const y of ticks(y0, y1, Math.max(2, h / 55))) {
        ctx.beginPath();
        ctx.moveTo(pad.left, Math.round(py(y)) + 0.5);
        ctx.lineTo(pad.left + w, Math.round(py(y)) + 0.5);
        ctx.stroke();
        ctx.fillText(o.yFormat(y), pad.left - 6, py(y));
      }
      ctx.strokeStyle = c.border;
      ctx.strokeRect(pad.left + 0.5, pad.top + 0.5, w - 1, h - 1);
      ctx.textAlign = 'center';
      ctx.textBaseline = 'bottom';
      ctx.fillText(o.xLabel, pad.left + w / 2, height - 2);
      ctx.save();
      ctx.translate(12, pad.top + h / 2);
      ctx.rotate(-Math.PI / 2);
      ctx.textBaseline = 'middle';
      ctx.fillText(o.yLabel, 0, 0);
      ctx.restore();
      return { px, py, pad, w, h, x0, x1, y0, y1 };
    }

    function polyline(ctx, points, colour, width, dash) {
      const drawn = points.filter(Boolean);
      if (drawn.length < 2) return;
      ctx.strokeStyle = colour;
      ctx.lineWidth = width;
      ctx.setLineDash(dash || []);
      ctx.beginPath();
      drawn.forEach(([x, y], i) => (i === 0 ? ctx.moveTo(x, y) : ctx.lineTo(x, y)));
      ctx.stroke();
      ctx.setLineDash([]);
    }

    // The machine from rear to front, thick, with the front as a dot.
    function machine(ctx, rear, front, c) {
      if (!rear || !front) return;
      ctx.strokeStyle = c.pred;
      ctx.lineWidth = 5;
      ctx.lineCap = 'round';
      ctx.beginPath();
      ctx.moveTo(...rear);
      ctx.lineTo(...front);
      ctx.stroke();
      ctx.lineCap = 'butt';
      ctx.fillStyle = c.fused;
      ctx.strokeStyle = c.panel;
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.arc(front[0], front[1], 5, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
    }

    // The drive, one point per station bucket, along the front's station.
    function drivePoints() {
      return [...state.drive.values()].sort((a, b) => a.fs - b.fs);
    }

    function drawPlan() {
      const canvas = $('dta-plan');
      const { ctx, width, height } = prepare(canvas);
      draws.plan += 1;
      const c = colours();
      const a = state.axis;
      if (a.length < 2) {
        ctx.fillStyle = c.muted;
        ctx.fillText('no design axis', 70, 30);
        return;
      }
      const drive = drivePoints();
      const track = drive.map((p) => planPoint(p.fs, p.fh));
      let [x0, x1, y0, y1] = [Infinity, -Infinity, Infinity, -Infinity];
      for (const p of a) {
        x0 = Math.min(x0, p.easting_m); x1 = Math.max(x1, p.easting_m);
        y0 = Math.min(y0, p.northing_m); y1 = Math.max(y1, p.northing_m);
      }
      const grow = Math.max(x1 - x0, y1 - y0) * 0.08 + 1;
      const f = frame(ctx, width, height, [x0 - grow, x1 + grow, y0 - grow, y1 + grow], {
        equal: true, xLabel: 'easting (m)', yLabel: 'northing (m)',
        xFormat: (v) => v.toFixed(0), yFormat: (v) => v.toFixed(0),
      }, c);
      const to = (p) => (p ? [f.px(p[0]), f.py(p[1])] : null);
      polyline(ctx, a.map((p) => [f.px(p.easting_m), f.py(p.northing_m)]), c.curve, 1.5, [8, 4]);
      // Station ticks across the axis, labelled on its left.
      const first = a[0].station_m, last = a[a.length - 1].station_m;
      ctx.fillStyle = c.muted;
      ctx.strokeStyle = c.muted;
      ctx.lineWidth = 1;
      ctx.font = '11px system-ui, sans-serif';
      const labelled = ticks(first, last, 5);
      for (const s of [first, ...labelled.filter((s) => s > first && s < last), last]) {
        const p = axisAt(s);
        const [x, y] = [f.px(p.e), f.py(p.n)];
        const [nx, ny] = [p.dn, p.de]; // the right normal on screen (y down)
        ctx.beginPath();
        ctx.moveTo(x - nx * 5, y - ny * 5);
        ctx.lineTo(x + nx * 5, y + ny * 5);
        ctx.stroke();
        ctx.textAlign = nx > 0.3 ? 'right' : nx < -0.3 ? 'left' : 'center';
        ctx.textBaseline = ny > 0.3 ? 'bottom' : ny < -0.3 ? 'top' : 'middle';
        ctx.fillText(chainage(s, 0), x - nx * 9, y - ny * 9);
      }
      ctx.font = '12px system-ui, sans-serif';
      polyline(ctx, track.map(to), c.fused, 3);
      const e = state.latest;
      if (e) machine(ctx, to(planPoint(e.rear.station_m, e.rear.horizontal_mm)), to(planPoint(e.front.station_m, e.front.horizontal_mm)), c);
      // North.
      const nx = f.pad.left + f.w - 22, ny = f.pad.top + 34;
      ctx.strokeStyle = c.fg;
      ctx.fillStyle = c.fg;
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.moveTo(nx, ny);
      ctx.lineTo(nx, ny - 18);
      ctx.stroke();
      arrowHead(ctx, nx, ny, nx, ny - 20, 8);
      ctx.textAlign = 'center';
      ctx.textBaseline = 'top';
      ctx.fillText('N', nx, ny + 2);
    }

    function drawProfile() {
      const canvas = $('dta-profile');
      const { ctx, width, height } = prepare(canvas);
      draws.profile += 1;
      const c = colours();
      const a = state.axis;
      if (a.length < 2) {
        ctx.fillStyle = c.muted;
        ctx.fillText('no design axis', 70, 30);
        return;
      }
      const drive = drivePoints();
      const height_ = (s, mm) => { const p = axisAt(s); return p && num(mm) ? p.h + mm / 1000 : null; };
      const track = drive.map((p) => [p.fs, height_(p.fs, p.fv)]).filter((p) => p[1] !== null);
      const x0 = a[0].station_m, x1 = a[a.length - 1].station_m;
      let [y0, y1] = [Infinity, -Infinity];
      for (const p of a) { y0 = Math.min(y0, p.height_m); y1 = Math.max(y1, p.height_m); }
      for (const [, h] of track) { y0 = Math.min(y0, h); y1 = Math.max(y1, h); }
      const span = Math.max(y1 - y0, 0.2);
      const ym = (y0 + y1) / 2;
      const f = frame(ctx, width, height, [x0, x1, ym - span * 0.6, ym + span * 0.6], {
        xLabel: 'station', yLabel: 'height (m)',
        xFormat: (v) => chainage(v, 0), yFormat: (v) => v.toFixed(span < 2 ? 2 : 1),
      }, c);
      const to = (s, h) => (h === null ? null : [f.px(s), f.py(h)]);
      polyline(ctx, a.map((p) => [f.px(p.station_m), f.py(p.height_m)]), c.curve, 1.5, [8, 4]);
      polyline(ctx, track.map(([s, h]) => to(s, h)), c.fused, 3);
      const e = state.latest;
      if (e) {
        machine(ctx, to(e.rear.station_m, height_(e.rear.station_m, e.rear.vertical_mm)),
          to(e.front.station_m, height_(e.front.station_m, e.front.vertical_mm)), c);
      }
      const exaggeration = (f.h / (f.y1 - f.y0)) / (f.w / (f.x1 - f.x0));
      setText($('dta-exaggeration'), `vertical ×${exaggeration >= 10 ? exaggeration.toFixed(0) : exaggeration.toFixed(1)}`);
    }

    function drawAxisNote() {
      const a = state.axis;
      if (a.length < 2) return;
      const name = section.dataset.axis;
      setText($('dta-axis-note'), `${name ? `axis ${name}: ` : 'axis: '}${chainage(a[0].station_m)} to ${chainage(a[a.length - 1].station_m)}`
        + ` (${fixed(a[a.length - 1].station_m - a[0].station_m, 1)} m); the deviations are millimetres, too small to see in plan: the charts above show them`);
    }

    // ---- deviation against station ----------------------------------------
    // Tolerance bands behind the series: warn to alarm and beyond alarm.
    function bands(lim) {
      return (u) => {
        if (!lim.warn || !lim.alarm) return;
        const ctx = u.ctx;
        const { left, top, width, height } = u.bbox;
        const ratio = window.devicePixelRatio || 1;
        const y = (v) => Math.max(top, Math.min(top + height, u.valToPos(v, 'y', true)));
        const band = (a, b, colour) => {
          const ya = y(a), yb = y(b);
          if (Math.abs(yb - ya) < 0.5) return;
          ctx.fillStyle = colour;
          ctx.fillRect(left, Math.min(ya, yb), width, Math.abs(yb - ya));
        };
        const c = colours();
        const far = 1e9;
        ctx.save();
        band(lim.alarm, far, c.badBg);
        band(-lim.alarm, -far, c.badBg);
        band(lim.warn, lim.alarm, c.warnBg);
        band(-lim.warn, -lim.alarm, c.warnBg);
        ctx.lineWidth = ratio;
        ctx.setLineDash([5 * ratio, 4 * ratio]);
        for (const [v, colour] of [[lim.warn, c.warn], [-lim.warn, c.warn], [lim.alarm, c.bad], [-lim.alarm, c.bad]]) {
          const yy = u.valToPos(v, 'y', true);
          if (yy < top || yy > top + height) continue;
          ctx.strokeStyle = colour;
          ctx.beginPath();
          ctx.moveTo(left, yy);
          ctx.lineTo(left + width, yy);
          ctx.stroke();
        }
        ctx.restore();
      };
    }

    // Where the front and rear are now: vertical lines.
    function nowLines(u) {
      const e = state.latest;
      if (!e) return;
      const ctx = u.ctx;
      const { top, height, left, width } = u.bbox;
      const ratio = window.devicePixelRatio || 1;
      const c = colours();
      ctx.save();
      ctx.lineWidth = ratio;
      ctx.font = `${11 * ratio}px system-ui, sans-serif`;
      ctx.textBaseline = 'top';
      for (const [s, label, colour] of [[e.front.station_m, 'front', c.fused], [e.rear.station_m, 'rear', c.pred]]) {
        const x = u.valToPos(s, 'x', true);
        if (!(x >= left && x <= left + width)) continue;
        ctx.strokeStyle = colour;
        ctx.fillStyle = colour;
        ctx.setLineDash([2 * ratio, 3 * ratio]);
        ctx.beginPath();
        ctx.moveTo(x, top);
        ctx.lineTo(x, top + height);
        ctx.stroke();
        ctx.textAlign = label === 'front' ? 'left' : 'right';
        ctx.fillText(label, x + (label === 'front' ? 4 : -4) * ratio, top + 3 * ratio);
      }
      ctx.restore();
    }

    // The steps between station ticks uPlot may choose, metres.
    const STATION_INCRS = [1, 2, 5, 10, 20, 25, 50, 100, 200, 250, 500, 1000, 2000, 5000, 10000, 20000, 50000];

    function stationRange(u, lo, hi) {
      if (!num(lo) || !num(hi)) return [0, 10];
      if (hi - lo < 10) { const m = (lo + hi) / 2; return [m - 5, m + 5]; }
      const pad = (hi - lo) * 0.02;
      return [lo - pad, hi + pad];
    }

    function deviationRange(lim) {
      return (u, lo, hi) => {
        const least = lim.alarm ? lim.alarm * 1.3 : 10;
        lo = num(lo) ? Math.min(lo * 1.1, -least) : -least;
        hi = num(hi) ? Math.max(hi * 1.1, least) : least;
        return [lo, hi];
      };
    }

    function stationChart(comp) {
      const el = $(`dta-${comp}-chart`);
      const lim = LIMITS[comp];
      const name = comp === 'h' ? 'horizontal' : 'vertical';
      const sign = comp === 'h' ? 'right +' : 'up +';
      return new uPlot({
        width: el.clientWidth || 800,
        height: CHART_HEIGHT,
        scales: { x: { time: false, range: stationRange }, y: { range: deviationRange(lim) } },
        series: [
          { label: 'station', value: (u, v) => (v == null ? '—' : chainage(v)) },
          line(`front ${name}`, css('--fused'), 'mm', 1, { width: 2 }),
          line(`rear ${name}`, css('--pred'), 'mm', 1, { width: 2, dash: [6, 3] }),
          line(`correction ${name}`, css('--warn'), 'mm', 1, { width: 2, dash: [2, 3], show: !!STEER }),
        ],
        axes: [
          // Whole metres between ticks (the range is at least 10 m), so
          // each tick has a label of its own: "1+003", "1+004", not
          // "1+003" twice at half metres.
          axis({ incrs: STATION_INCRS, values: (u, splits) => splits.map((s) => chainage(s, 0)), size: 36 }),
          axis({ label: `${name} (mm, ${sign})`, size: 64 }),
        ],
        hooks: { drawClear: [bands(lim)], draw: [nowLines] },
        cursor: { drag: { x: false, y: false } },
      }, [[], [], [], []], el);
    }

    function createCharts() {
      for (const chart of Object.values(charts)) chart.destroy();
      for (const comp of COMPONENTS) {
        $(`dta-${comp}-chart`).textContent = '';
        charts[comp] = stationChart(comp);
      }
    }

    // The front's and the rear's deviations, each at its own station, and
    // the correction curve ahead of the front, on one sorted x (null where
    // a series has no value there).
    function driveSeries() {
      const rows = new Map(); // station → [fh, fv, rh, rv, ch, cv]
      const put = (x, i, a, b) => {
        if (!num(x)) return;
        let row = rows.get(x);
        if (!row) rows.set(x, (row = [null, null, null, null, null, null]));
        row[i] = a;
        row[i + 1] = b;
      };
      for (const p of state.drive.values()) {
        put(p.fs, 0, p.fh, p.fv);
        put(p.rs, 2, p.rh, p.rv);
      }
      for (const p of curvePoints()) put(p.s, 4, p.h, p.v);
      const xs = [...rows.keys()].sort((a, b) => a - b);
      const column = (i) => xs.map((x) => rows.get(x)[i]);
      return { xs, fh: column(0), fv: column(1), rh: column(2), rv: column(3), ch: column(4), cv: column(5) };
    }

    function drawStationCharts() {
      if (!charts.h) return;
      const d = driveSeries();
      charts.h.setData([d.xs, d.fh, d.rh, d.ch]);
      charts.v.setData([d.xs, d.fv, d.rv, d.cv]);
      const n = state.drive.size;
      if (n === 0) {
        setText($('dta-drive-note'), 'no positions yet');
        return;
      }
      const stations = [...state.drive.values()].map((p) => p.s);
      const how = state.downsampled ? '; the history downsampled by the server' : '';
      setText($('dta-drive-note'), `${n} positions from ${chainage(Math.min(...stations), 1)} to ${chainage(Math.max(...stations), 1)}`
        + ` (the newest per ${STATION_BUCKET_M * 100} cm of station${how})${LIMITED ? '; the bands: warn and alarm' : ''}`);
    }

    function drawCanvases() {
      drawTarget();
      drawPlan();
      drawProfile();
    }

    const redraw = tn.debounce(() => {
      refreshSteering();
      showReadouts();
      drawStationCharts();
      drawCanvases();
    }, 150);

    // ---- live ---------------------------------------------------------------
    function connect() {
      const live = tn.followEngine(API, 'dta', {
        state, add, redraw, windowStart: () => (state.latest ? state.latest.t : 0),
      }, BACKFILL_POINTS);
      Object.defineProperty(window.tunnelnavDta, 'socket', { get: () => live.socket });
    }

    async function start() {
      createCharts();
      drawCanvases();
      await tn.runSection({
        root: section,
        charts,
        onTheme: () => {
          createCharts();
          drawStationCharts();
          drawCanvases();
        },
        resized: drawCanvases,
        every: [[showAge, 1000]],
        load: async () => {
          await Promise.all([loadAxis(), loadDrive()]);
          drawAxisNote();
          redraw();
        },
        connect,
      });
    }

    start();
  },
});
