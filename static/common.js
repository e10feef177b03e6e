// tunnelnav dashboard: what every page shares (the server clock, number and
// duration formats, JSON fetches, the theme toggle). No framework.
'use strict';

const tn = (function () {
  // The server's clock: Unix seconds, possibly accelerated (the demo runs
  // it faster than real time). Synced from `server_t` and `clock_rate`,
  // which the status endpoints and the live socket's hello/ping carry.
  const clock = {
    serverT: null, rate: 1, syncedAt: 0,
    sync(serverT, rate) {
      if (typeof serverT !== 'number') return;
      this.serverT = serverT;
      if (typeof rate === 'number' && rate > 0) this.rate = rate;
      this.syncedAt = performance.now();
      showClock();
    },
    // Stopped at the last good contact while the connection is lost.
    frozenT: null,
    now() {
      if (this.frozenT !== null) return this.frozenT;
      if (this.serverT === null) return Date.now() / 1000;
      return this.serverT + (performance.now() - this.syncedAt) / 1000 * this.rate;
    },
  };

  // The page's links to the server (its polls and sockets, by name). Any
  // one failing (network, 401, server down) turns the page to "connection
  // lost — data as of HH:MM:SS" and stops the clock until all are back:
  // stale data is never shown as live.
  const link = {
    failing: new Map(),
    lastGoodT: null,
    ok(source) {
      this.lastGoodT = clock.frozenT === null ? clock.now() : clock.serverT;
      if (!this.failing.delete(source)) return;
      if (this.failing.size === 0) clock.frozenT = null;
      showLink();
    },
    failed(source, reason) {
      if (this.failing.size === 0) clock.frozenT = this.lastGoodT !== null ? this.lastGoodT : clock.now();
      this.failing.set(source, reason);
      showLink();
    },
    lost() { return this.failing.size > 0; },
  };

  function hhmmss(t) {
    return new Date(t * 1000).toLocaleTimeString([], { hour12: false });
  }

  function showLink() {
    const el = document.getElementById('conn-lost');
    const lost = link.lost();
    document.body.classList.toggle('offline', lost);
    if (!el) return;
    el.hidden = !lost;
    if (!lost) return;
    const reasons = [...new Set(link.failing.values())];
    const signedOut = reasons.some((r) => /\b401\b/.test(r));
    const asOf = link.lastGoodT !== null ? hhmmss(link.lastGoodT) : 'never';
    el.innerHTML = '';
    const strong = document.createElement('strong');
    strong.textContent = `connection lost — data as of ${asOf}`;
    el.append(strong, ` (${reasons.join('; ')})`);
    if (signedOut) {
      const a = document.createElement('a');
      a.href = "/login";
      a.textContent = 'sign in again';
      el.append(' · ', a);
    }
    showClock();
  }

  // Closes a socket that has been silent for longer than two of the
  // server's 10 s pings (a network gone without a reset): its onclose
  // then reports the loss and reconnects.
  function silenceWatchdog(socket) {
    let last = performance.now();
    const timer = setInterval(() => {
      if (performance.now() - last > 25000) socket.close();
    }, 1000);
    return { heard() { last = performance.now(); }, stop() { clearInterval(timer); } };
  }

  const DEG = Math.PI / 180;

  function fixed(value, digits) {
    return (typeof value === 'number' && isFinite(value)) ? value.toFixed(digits) : '—';
  }

  // A slope in degrees as millimetres per metre (tan of the angle × 1000).
  function mmPerM(deg) {
    return (typeof deg === 'number' && isFinite(deg)) ? Math.tan(deg * DEG) * 1000 : NaN;
  }

  // "42 s", "3 min 05 s", "2 h 04 min", "3 d 2 h".
  function duration(s) {
    if (typeof s !== 'number' || !isFinite(s)) return '—';
    s = Math.max(0, s);
    if (s < 60) return `${Math.floor(s)} s`;
    const pad = (n) => String(n).padStart(2, '0');
    if (s < 3600) return `${Math.floor(s / 60)} min ${pad(Math.floor(s % 60))} s`;
    if (s < 86400) return `${Math.floor(s / 3600)} h ${pad(Math.floor((s % 3600) / 60))} min`;
    return `${Math.floor(s / 86400)} d ${Math.floor((s % 86400) / 3600)} h`;
  }

  // Whether an estimate is too old to show as live: its age beyond five of
  // the intervals its stream has been seen to update at, and at least
  // `minS` (as the stale-sensor alarm judges a sensor). Keyed per stream;
  // the interval is learned from the distinct times seen.
  function freshness(minS = 30) {
    const seen = new Map(); // key → { t, interval }
    return {
      // The `estimate` of `key`, seen at `now`: { stale, age, notLive }
      // (not live: stale, or lost).
      judge(key, estimate, now) {
        const t = estimate.t;
        if (typeof t !== 'number') return { stale: false, age: null, notLive: estimate.integrity === 'lost' };
        const was = seen.get(key);
        if (!was) seen.set(key, { t, interval: null });
        else if (t > was.t) seen.set(key, { t, interval: t - was.t });
        const interval = (seen.get(key) || {}).interval;
        const age = now - t;
        const limit = Math.max(minS, 5 * (interval || 0));
        const stale = age > limit;
        return { stale, age, notLive: stale || estimate.integrity === 'lost' };
      },
    };
  }

  // An estimate's integrity in words: "LOST · tilt disagrees",
  // "degraded · recovering", or "" when ok (docs/protocol.md, "Integrity").
  function integrityWords(estimate) {
    const level = { lost: 'LOST', degraded: 'degraded' }[estimate.integrity];
    if (!level) return '';
    return estimate.integrity_reason ? `${level} · ${estimate.integrity_reason.replace(/_/g, ' ')}` : level;
  }

  // A note on an estimate that is not live: its integrity when not ok, and
  // its age when stale ("" for a live, vouched-for estimate).
  function trustNote(estimate, judged) {
    const parts = [integrityWords(estimate)];
    if (judged && judged.stale) parts.push(`${duration(judged.age)} old`);
    return parts.filter(Boolean).join(' · ');
  }

  // A station as chainage, kilometres + metres, rounded to `digits`
  // decimals of a metre as whole units (as the reports do: 1234.5 →
  // "1+234.500"; no sign on what rounds to nothing).
  function chainage(s, digits = 3) {
    if (!num(s)) return '\u2014';
    const scale = 10 ** digits;
    const units = Math.round(Math.abs(s) * scale);
    const sign = s < 0 && units > 0 ? '\u2212' : '';
    const perKm = 1000 * scale;
    const km = Math.floor(units / perKm);
    const rest = units - km * perKm;
    const m = Math.floor(rest / scale);
    const fraction = digits > 0 ? `.${String(rest - m * scale).padStart(digits, '0')}` : '';
    return `${sign}${km}+${String(m).padStart(3, '0')}${fraction}`;
  }

  function timeOfDay(t) {
    if (typeof t !== 'number' || !isFinite(t)) return '—';
    return new Date(t * 1000).toLocaleString([], { hour12: false });
  }

  async function json(url) {
    // A request the network swallowed fails after 10 s instead of hanging.
    const abort = new AbortController();
    const timer = setTimeout(() => abort.abort(), 10000);
    let response;
    try {
      response = await fetch(url, { headers: { Accept: 'application/json' }, signal: abort.signal });
    } catch (e) {
      throw new Error(e.name === 'AbortError' ? `${url}: no answer within 10 s` : `${url}: server unreachable`);
    } finally {
      clearTimeout(timer);
    }
    if (!response.ok) {
      let reason = response.statusText;
      try { reason = (await response.json()).error || reason; } catch (e) { /* not JSON */ }
      throw new Error(`${url}: ${response.status} ${reason}`);
    }
    return response.json();
  }

  // NDJSON lines of `url`, at most `limit` of them (the rest is not read).
  async function ndjson(url, limit) {
    const response = await fetch(url);
    if (!response.ok) throw new Error(`${url}: ${response.status}`);
    const reader = response.body.getReader();
    const decoder = new TextDecoder();
    const out = [];
    let rest = '';
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      rest += decoder.decode(value, { stream: true });
      const lines = rest.split('\n');
      rest = lines.pop();
      for (const line of lines) {
        if (line.trim()) out.push(JSON.parse(line));
        if (out.length >= limit) { reader.cancel(); return out; }
      }
    }
    if (rest.trim()) out.push(JSON.parse(rest));
    return out;
  }

  function setText(el, text) {
    if (el && el.textContent !== text) el.textContent = text;
  }

  function css(name) {
    return getComputedStyle(document.documentElement).getPropertyValue(name).trim();
  }

  // Header: theme toggle and the server clock.
  document.getElementById('theme-toggle').addEventListener('click', () => {
    const root = document.documentElement;
    root.dataset.theme = root.dataset.theme === 'dark' ? 'light' : 'dark';
    try { localStorage.setItem('tunnelnav-theme', root.dataset.theme); } catch (e) { /* private mode */ }
    window.dispatchEvent(new Event('tn-theme'));
  });
  function showClock() {
    const el = document.getElementById('server-clock');
    if (!el || clock.serverT === null) return;
    const rate = clock.rate === 1 ? '' : ` (×${clock.rate})`;
    const stopped = clock.frozenT !== null;
    el.classList.toggle('stopped', stopped);
    setText(el, `server clock ${timeOfDay(clock.now())}${rate}${stopped ? ' (stopped)' : ''}`);
  }
  setInterval(showClock, 250);

  // A machine page's connection line: connecting, live, reconnecting,
  // fetching missed estimates, or live with what a backfill brought.
  function showConnection(el, connection, detail) {
    el.dataset.state = connection;
    const text = {
      connecting: 'connecting…',
      live: '● live',
      reconnecting: 'reconnecting…',
      backfilling: 'fetching missed estimates…',
      backfilled: `● live · ${detail}`,
    }[connection];
    setText(el, text || connection);
  }

  // Follows a machine's `live` socket, reconnecting with back-off. `on`
  // has hello(message, isReconnect), estimate(message), gap(message) and
  // closed(); hello and ping sync the clock, unknown events are ignored.
  // The returned handle's `socket` is the current WebSocket.
  let links = 0;
  function follow(api, on) {
    const handle = { socket: null };
    const name = `live ${api} #${++links}`;
    let retryMs = 500, connected = false;
    function connect() {
      const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
      const socket = new WebSocket(`${scheme}//${location.host}${api}/live`);
      handle.socket = socket;
      const watchdog = silenceWatchdog(socket);
      socket.onmessage = (event) => {
        watchdog.heard();
        let m;
        try { m = JSON.parse(event.data); } catch (e) { return; }
        if (m.event === 'hello') {
          retryMs = 500;
          clock.sync(m.server_t, m.clock_rate);
          link.ok(name);
          on.hello(m, connected);
          connected = true;
        } else if (m.event === 'ping') {
          clock.sync(m.server_t, m.clock_rate || clock.rate);
          link.ok(name);
        } else if (m.event === 'gap') {
          on.gap(m);
        } else if (m.event === undefined && m.engine) {
          on.estimate(m);
        }
      };
      socket.onclose = () => {
        watchdog.stop();
        link.failed(name, 'live stream closed');
        on.closed();
        setTimeout(connect, retryMs);
        retryMs = Math.min(retryMs * 2, 10000);
      };
    }
    connect();
    return handle;
  }

  // The sensors table of a machine page from its status.
  function showSensors(body, status) {
    const rows = Object.entries(status.sensors || {}).map(([name, sensor]) =>
      `<tr><td>${name}</td><td>${timeOfDay(sensor.last_t)}</td>` +
      `<td>${duration(status.server_t - sensor.last_t)}</td><td>${sensor.readings}</td></tr>`).join('');
    const html = rows || '<tr><td colspan="4">no readings yet</td></tr>';
    if (body.innerHTML !== html) body.innerHTML = html;
  }

  // A machine page's status every 2 s: syncs the clock and fills the
  // sensors table. Resolves after the first poll.
  async function pollStatus(api, body) {
    const name = `status ${api} #${++links}`;
    const poll = latestOnly(async () => json(api), (s) => {
      clock.sync(s.server_t, s.clock_rate);
      link.ok(name);
      showSensors(body, s);
    }, (e) => link.failed(name, e.message));
    await poll();
    setInterval(poll, 2000);
  }

  // A poll whose answers are used only if no later poll has answered
  // first (polls overlap when the server is slow): `fetch()` resolves to
  // the answer, `use(answer)` or `fail(error)` takes it.
  function latestOnly(fetchIt, use, fail) {
    let started = 0, settled = 0;
    return async () => {
      const mine = ++started;
      let answer;
      try {
        answer = await fetchIt();
      } catch (e) {
        if (mine < settled) return;
        settled = mine;
        fail(e);
        return;
      }
      if (mine < settled) return;
      settled = mine;
      use(answer);
    };
  }

  // A group of time-window buttons: the clicked one becomes active and
  // onSelect gets its window in seconds.
  function windowButtons(group, onSelect) {
    const buttons = document.querySelectorAll(`${group} button`);
    buttons.forEach((button) => button.addEventListener('click', () => {
      buttons.forEach((b) => b.classList.toggle('active', b === button));
      onSelect(Number(button.dataset.window));
    }));
  }

  // A uPlot axis in the page's colours.
  function axis(extra) {
    return Object.assign({
      stroke: css('--muted'),
      grid: { stroke: css('--grid'), width: 1 },
      ticks: { stroke: css('--grid'), width: 1 },
    }, extra || {});
  }

  function num(v) {
    return typeof v === 'number' && isFinite(v);
  }

  // The live socket of one engine's part of a machine page, with backfill
  // from the history API after a reconnect or a `gap` event. `page` holds
  // `state` (connection, lastLiveT, backfilled), `add(estimate, thin)`,
  // `redraw()` and `windowStart()`. Returns the `follow` handle.
  function followEngine(api, engine, page, backfillPoints) {
    const { state } = page;
    const setConnection = (connection, detail) => {
      state.connection = connection;
      showConnection(document.getElementById('conn-state'), connection, detail);
    };
    async function backfill(fromT, why) {
      setConnection('backfilling');
      try {
        const history = await json(`${api}/estimates?engine=${engine}&from=${fromT}&max_points=${backfillPoints}`);
        for (const e of history.estimates) page.add(e, false);
        state.backfilled += history.estimates.length;
        setConnection('backfilled', `${why}: ${history.estimates.length} estimates backfilled`);
        setTimeout(() => { if (state.connection === 'backfilled') setConnection('live'); }, 15000);
        page.redraw();
      } catch (e) {
        console.error('backfill:', e.message);
        setConnection('live');
      }
    }
    return follow(api, {
      hello(m, isReconnect) {
        const resumeFrom = state.lastLiveT;
        if (m.latest && m.latest[engine]) page.add(m.latest[engine], false);
        if (isReconnect && resumeFrom !== null) backfill(resumeFrom, 'reconnected');
        else setConnection('live');
        page.redraw();
      },
      gap(m) {
        backfill(num(m.from_t) ? m.from_t : page.windowStart(), `fell behind (${m.missed} missed)`);
      },
      estimate(m) {
        if (m.engine !== engine) return;
        page.add(m, true);
        state.lastLiveT = Math.max(state.lastLiveT || 0, m.t);
        page.redraw();
      },
      closed() { setConnection('reconnecting'); },
    });
  }

  // A uPlot drawClear hook shading the spans where `on(point)` holds, over
  // the time-sorted `points()` (zero velocity, static).
  function shadeSpans(points, on) {
    return (u) => {
      const ctx = u.ctx;
      ctx.save();
      ctx.fillStyle = css('--still');
      const top = u.bbox.top, height = u.bbox.height;
      let from = null, previous = null;
      const flush = (to) => {
        const x0 = Math.max(u.bbox.left, u.valToPos(from, 'x', true));
        const x1 = Math.min(u.bbox.left + u.bbox.width, u.valToPos(to, 'x', true));
        if (x1 > x0) ctx.fillRect(x0, top, Math.max(1, x1 - x0), height);
      };
      for (const p of points()) {
        if (on(p) && from === null) from = p.t;
        if (!on(p) && from !== null) { flush(p.t); from = null; }
        previous = p;
      }
      if (from !== null && previous) flush(previous.t);
      ctx.restore();
    };
  }

  // A uPlot line series; uPlot takes an explicit `undefined` as a value,
  // so scale and dash are only set when given in `extra`.
  function line(label, color, unit, digits, extra) {
    return Object.assign({ label, stroke: color, width: 1.5, spanGaps: true, points: { show: false },
      value: (u, v) => (v == null ? '—' : `${v.toFixed(digits)} ${unit}`) }, extra || {});
  }

  // `draw` debounced: however often the function returned is called, draw
  // runs once, `delayMs` after the first call.
  function debounce(draw, delayMs) {
    let timer = null;
    return () => {
      if (timer !== null) return;
      timer = setTimeout(() => {
        timer = null;
        draw();
      }, delayMs);
    };
  }

  // Each uPlot chart of `charts` fitted to its element's width (its
  // height kept).
  function fitCharts(charts) {
    for (const chart of Object.values(charts)) {
      const el = chart && chart.root ? chart.root.parentElement : null;
      if (el && el.clientWidth && Math.abs(chart.width - el.clientWidth) > 2) {
        chart.setSize({ width: el.clientWidth, height: chart.height });
      }
    }
  }

  // The life of an engine's or stage's section of a machine page, once
  // its charts exist: on a theme change `onTheme()` (the charts made in
  // the new colours); when `root` changes size, each chart of `charts`
  // fitted and `resized()`; each [job, ms] of `every` run every ms; then
  // `load()` (the history) awaited and `connect()` (the live socket).
  async function runSection({ root, charts, onTheme, resized, every = [], load, connect }) {
    window.addEventListener('tn-theme', onTheme);
    new ResizeObserver(() => {
      fitCharts(charts);
      if (resized) resized();
    }).observe(root);
    for (const [job, ms] of every) setInterval(job, ms);
    if (load) await load();
    connect();
  }

  // Each engine's script registers its part of the dashboard by the
  // engine's protocol name: `card(latest)` gives the fleet card's rows
  // ([label, text] pairs) from its newest estimate, `page()` runs its
  // section of a machine page (static/machine.js starts the machine's).
  const engines = {};
  function registerEngine(name, parts) {
    engines[name] = parts;
  }

  return {
    clock, link, silenceWatchdog, latestOnly, fixed, mmPerM, duration, freshness, integrityWords, trustNote, timeOfDay, chainage, json, ndjson, setText, css,
    showConnection, follow, showSensors, pollStatus, windowButtons, axis, num,
    shadeSpans, line, followEngine, debounce, runSection, engines, registerEngine,
  };
})();
