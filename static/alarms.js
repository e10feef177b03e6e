// The fleet-wide alarm bar on every page: follows /api/v1/alarms/live
// (hello with the active alarms, then raised / cleared / acknowledged),
// lists them by severity (alarms first), then newest first, acknowledges, chimes
// for new unacknowledged ones (toggle remembered), and colours the fleet
// cards. The socket counts as one of the page's connections (tn.link).
'use strict';

(function () {
  const bar = document.getElementById('alarm-bar');
  if (!bar) return;
  const summary = document.getElementById('alarm-summary');
  const list = document.getElementById('alarm-list');
  const chime = document.getElementById('alarm-chime');
  const toggle = document.getElementById('chime-toggle');
  const hint = document.getElementById('chime-hint');
  const ackError = document.getElementById('alarm-error');
  const ackedBox = document.getElementById('alarms-acked');
  const ackedSummary = ackedBox.querySelector('summary');
  const ackedList = document.getElementById('alarm-acked-list');
  const active = new Map(); // id → alarm
  const cleared = new Set(); // ids seen cleared: never shown again
  const acking = new Set(); // ids whose acknowledgement is on its way
  const STORE_KEY = 'tunnelnav-chime';
  // Ids already chimed for, over the pages of this tab (moving between
  // pages does not ring again).
  const CHIMED_KEY = 'tunnelnav-chimed';
  const chimed = new Set((() => {
    try { return JSON.parse(sessionStorage.getItem(CHIMED_KEY) || '[]'); } catch (e) { return []; }
  })());

  // --- chime: a short two-tone WAV built here (no binary asset) ---------
  function chimeWav() {
    const rate = 22050, seconds = 0.9;
    const n = Math.floor(rate * seconds);
    const data = new DataView(new ArrayBuffer(44 + 2 * n));
    const text = (at, s) => { for (let i = 0; i < s.length; i++) data.setUint8(at + i, s.charCodeAt(i)); };
    text(0, 'RIFF'); data.setUint32(4, 36 + 2 * n, true); text(8, 'WAVE');
    text(12, 'fmt '); data.setUint32(16, 16, true); data.setUint16(20, 1, true);
    data.setUint16(22, 1, true); data.setUint32(24, rate, true); data.setUint32(28, 2 * rate, true);
    data.setUint16(32, 2, true); data.setUint16(34, 16, true);
    text(36, 'data'); data.setUint32(40, 2 * n, true);
    for (let i = 0; i < n; i++) {
      const t = i / rate;
      const f = t < seconds / 2 ? 880 : 660;
      const local = t < seconds / 2 ? t : t - seconds / 2;
      const envelope = Math.exp(-6 * local);
      data.setInt16(44 + 2 * i, Math.round(12000 * envelope * Math.sin(2 * Math.PI * f * t)), true);
    }
    return URL.createObjectURL(new Blob([data], { type: 'audio/wav' }));
  }
  chime.src = chimeWav();
  let started = 0;
  chime.addEventListener('playing', () => { started += 1; chime.dataset.started = String(started); });

  function chimeOn() {
    try { return localStorage.getItem(STORE_KEY) !== 'off'; } catch (e) { return true; }
  }
  function showToggle() {
    const on = chimeOn();
    toggle.setAttribute('aria-pressed', String(on));
    tn.setText(toggle, on ? '♪ chime on' : '♪ chime off');
  }
  toggle.addEventListener('click', () => {
    try { localStorage.setItem(STORE_KEY, chimeOn() ? 'off' : 'on'); } catch (e) { /* private mode */ }
    showToggle();
  });
  showToggle();

  function ring() {
    if (!chimeOn()) return;
    chime.currentTime = 0;
    const playing = chime.play();
    if (playing && playing.catch) {
      playing.then(() => { hint.hidden = true; }).catch((e) => {
        // Browsers refuse sound before the first click on the page.
        if (e && e.name === 'NotAllowedError') {
          hint.hidden = false;
          document.addEventListener('click', () => { hint.hidden = true; }, { once: true });
        }
      });
    }
  }

  // --- the bar ------------------------------------------------------------
  const escape = (s) => String(s).replace(/[&<>"']/g, (c) => ({
    '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;',
  }[c]));

  // The worst first: alarms before warnings, then the newest first.
  const rank = (a) => (a.severity === 'alarm' ? 0 : 1);
  function sorted() {
    return [...active.values()].sort((a, b) =>
      (rank(a) - rank(b)) || (b.raised_t - a.raised_t) || (b.id - a.id));
  }

  // Unacknowledged alarms are listed (alarms, then warnings; newest first) with their button;
  // acknowledged ones that are still active fold into a line below, so
  // acknowledging takes an alarm off the list but not out of sight.
  function render() {
    const alarms = sorted();
    const open = alarms.filter((a) => a.acked_t == null);
    const acked = alarms.filter((a) => a.acked_t != null);
    bar.hidden = alarms.length === 0;
    const worstOf = (list) => (list.some((a) => a.severity === 'alarm') ? 'alarm'
      : (list.length ? 'warn' : ''));
    bar.dataset.worst = open.length ? worstOf(open) : (acked.length ? 'acked' : 'none');
    const label = { alarm: 'ALARM', warn: 'WARNING' }[worstOf(alarms)] || '';
    tn.setText(summary, alarms.length === 0 ? '' :
      `${label} · ${alarms.length} active alarm${alarms.length === 1 ? '' : 's'} · ` +
      `${open.length} unacknowledged`);
    const row = (a, button) => {
      const cls = a.severity === 'alarm' ? 'bad' : 'warn';
      const end = button
        ? `<button type="button" class="ack" data-id="${a.id}"${acking.has(a.id) ? ' disabled' : ''}>Acknowledge</button>`
        : `<span class="acked">acknowledged by ${escape(a.acked_by || '?')} ${tn.timeOfDay(a.acked_t)}</span>`;
      return `<li class="alarm ${cls}" data-id="${a.id}">` +
        `<span class="badge ${cls}">${a.severity === 'alarm' ? 'ALARM' : 'warn'}</span> ` +
        `<a href="/machines/${encodeURIComponent(a.machine)}">${escape(a.machine)}</a> ` +
        `<span class="message">${escape(a.message)}</span> ` +
        (a.now ? `<span class="now">· now ${escape(a.now.value)}</span> ` : '') +
        `<span class="since">since ${tn.timeOfDay(a.raised_t)}</span> ${end}</li>`;
    };
    const html = open.map((a) => row(a, true)).join('');
    if (list.innerHTML !== html) list.innerHTML = html;
    ackedBox.hidden = acked.length === 0;
    tn.setText(ackedSummary, `${acked.length} acknowledged, still active`);
    const ackedHtml = acked.map((a) => row(a, false)).join('');
    if (ackedList.innerHTML !== ackedHtml) ackedList.innerHTML = ackedHtml;
    colourCards(alarms);
  }

  // Fleet cards (and the machine page's heading): worst severity each.
  function colourCards(alarms) {
    const worstOf = new Map();
    for (const a of alarms) {
      const was = worstOf.get(a.machine);
      if (was !== 'alarm') worstOf.set(a.machine, a.severity);
    }
    document.querySelectorAll('[data-machine]').forEach((el) => {
      const worst = worstOf.get(el.dataset.machine) || '';
      if (el.dataset.alarm !== worst) el.dataset.alarm = worst;
      const line = el.querySelector('[data-field="alarms"]');
      if (line) {
        const n = alarms.filter((a) => a.machine === el.dataset.machine).length;
        tn.setText(line, n ? `⚠ ${n} active alarm${n === 1 ? '' : 's'}` : '');
        line.className = `alarm-line ${worst === 'alarm' ? 'bad' : (worst ? 'warn' : '')}`;
      }
    });
  }

  list.addEventListener('click', async (event) => {
    const button = event.target.closest('button.ack');
    if (!button) return;
    event.preventDefault();
    const id = Number(button.dataset.id);
    acking.add(id);
    ackError.hidden = true;
    render();
    const abort = new AbortController();
    const timer = setTimeout(() => abort.abort(), 10000);
    try {
      const response = await fetch(`/api/v1/alarms/${id}/ack`, { method: 'POST', signal: abort.signal });
      if (!response.ok) {
        let reason = response.statusText;
        try { reason = (await response.json()).error || reason; } catch (e) { /* not JSON */ }
        throw new Error(`${response.status} ${reason}`);
      }
      update({ transition: 'acknowledged', ...(await response.json()) });
    } catch (e) {
      const why = e.name === 'AbortError' ? 'no answer within 10 s' : e.message;
      tn.setText(ackError, `alarm ${id} not acknowledged: ${why}; try again`);
      ackError.hidden = false;
    } finally {
      clearTimeout(timer);
      acking.delete(id);
      render();
    }
  });

  // One raised, cleared or acknowledged alarm.
  function update(change) {
    const { transition, event, ...alarm } = change;
    if (transition === 'cleared' || alarm.cleared_t != null) cleared.add(alarm.id);
    if (cleared.has(alarm.id)) active.delete(alarm.id);
    else active.set(alarm.id, { ...alarm, now: alarm.now || (active.get(alarm.id) || {}).now });
    refresh();
  }

  // What each active alarm's quantity reads now (the message keeps the
  // value at the raise): asked every 5 s while any is active. Only the
  // `now` of alarms already listed is taken: the socket says which are.
  async function readNow() {
    if (active.size === 0) return;
    try {
      const response = await fetch('/api/v1/alarms?state=active');
      if (!response.ok) return;
      const { alarms } = await response.json();
      let changed = false;
      for (const a of alarms) {
        const shown = active.get(a.id);
        if (shown && JSON.stringify(shown.now) !== JSON.stringify(a.now)) {
          shown.now = a.now;
          changed = true;
        }
      }
      if (changed) render();
    } catch (e) { /* the socket's link state says the server is away */ }
  }
  setInterval(readNow, 5000);

  // The whole active list (on hello, or after falling behind).
  function replace(alarms) {
    active.clear();
    for (const a of alarms) active.set(a.id, a);
    refresh();
  }

  // Redraws; chimes once for each unacknowledged alarm not chimed for yet.
  function refresh() {
    const fresh = sorted().filter((a) => a.acked_t == null && !chimed.has(a.id));
    fresh.forEach((a) => chimed.add(a.id));
    if (fresh.length) {
      try { sessionStorage.setItem(CHIMED_KEY, JSON.stringify([...chimed].slice(-500))); } catch (e) { /* private mode */ }
    }
    render();
    if (fresh.length) ring();
  }

  // --- the socket, reconnecting with back-off -----------------------------
  let retryMs = 500;
  function connect() {
    const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
    const socket = new WebSocket(`${scheme}//${location.host}/api/v1/alarms/live`);
    let opened = false;
    const watchdog = tn.silenceWatchdog(socket);
    socket.onmessage = (message) => {
      watchdog.heard();
      let m;
      try { m = JSON.parse(message.data); } catch (e) { return; }
      if (m.event === 'hello') {
        opened = true;
        retryMs = 500;
        tn.clock.sync(m.server_t, m.clock_rate);
        tn.link.ok('alarms');
        replace(m.alarms);
      } else if (m.event === 'alarm') {
        update(m);
      } else if (m.event === 'alarm_gap') {
        // Fell behind: reconnect, and the new hello has the whole list.
        socket.close();
      } else if (m.event === 'ping') {
        tn.clock.sync(m.server_t, m.clock_rate || tn.clock.rate);
        tn.link.ok('alarms');
      }
    };
    socket.onclose = () => {
      watchdog.stop();
      tn.link.failed('alarms', opened ? 'alarm stream closed' : 'alarm stream: no connection');
      setTimeout(connect, retryMs);
      retryMs = Math.min(retryMs * 2, 10000);
    };
  }
  connect();
})();
