// A machine page: starts the section of each engine the machine runs
// (each engine's script registered itself with tn.registerEngine).
'use strict';

(function () {
  const root = document.getElementById('machine');
  for (const name of root.dataset.engines.split(',').map((n) => n.trim()).filter(Boolean)) {
    const engine = tn.engines[name];
    if (engine) engine.page();
    else console.warn(`no dashboard script for the ${name} engine`);
  }

  // The banner at the top: a laser dropout and every stream whose newest
  // estimate is not `ok`, worst first, so what cannot be trusted is said
  // before any number is read (docs/protocol.md, "Integrity").
  const banner = document.getElementById('trust-banner');
  const api = `/api/v1/machines/${encodeURIComponent(root.dataset.machine)}`;
  const show = (status) => {
    const lines = [];
    const laser = status.laser;
    if (laser && laser.dropout) {
      const out = (laser.age_s || 0) + (tn.clock.now() - laser.t);
      lines.push(['bad', `LASER DROPOUT · no laser sample for ${tn.duration(out)}`]);
    }
    const streams = Object.entries(status.latest || {})
      .filter(([, e]) => e && e.integrity && e.integrity !== 'ok')
      .sort(([, a], [, b]) => (a.integrity === 'lost' ? 0 : 1) - (b.integrity === 'lost' ? 0 : 1));
    for (const [name, e] of streams) {
      lines.push([e.integrity === 'lost' ? 'bad' : 'warn',
        `${name}: ${tn.integrityWords(e)}${e.integrity === 'lost' ? ' · its values cannot be vouched for' : ' · its σ is widened'}`]);
    }
    const html = lines.map(([cls, text]) => `<div class="trust-line ${cls}">${text}</div>`).join('');
    if (banner.innerHTML !== html) banner.innerHTML = html;
    banner.hidden = lines.length === 0;
  };
  // The ring log: the last rings built, fetched again when a new one is
  // logged (the status's newest `rings` record).
  const RINGS_SHOWN = 10;
  let ringsFor = null;
  const signed = (v, digits) => (tn.num(v) ? `${v > 0 ? '+' : v < 0 ? '\u2212' : ''}${Math.abs(v).toFixed(digits)}` : '—');
  const showRings = (page) => {
    const rings = (page.estimates || []).slice(-RINGS_SHOWN).reverse();
    const rows = rings.map((r) => {
      const row = document.createElement('tr');
      for (const text of [String(r.ring), tn.timeOfDay(r.t), tn.chainage(r.station_m),
        tn.num(r.advance_m) ? r.advance_m.toFixed(3) : '—',
        signed(r.front_horizontal_mm, 1), signed(r.front_vertical_mm, 1),
        signed(r.tendency_horizontal_mm_per_m, 2), signed(r.tendency_vertical_mm_per_m, 2),
        Array.isArray(r.strokes_mm) ? r.strokes_mm.map((v) => v.toFixed(0)).join(' ') : '—']) {
        const cell = document.createElement('td');
        cell.textContent = text;
        row.appendChild(cell);
      }
      return row;
    });
    document.querySelector('#ring-log-table tbody').replaceChildren(...rows);
    tn.setText(document.getElementById('ring-log-note'), rings.length
      ? `the last ${rings.length} rings, newest first; the full log as CSV, every ring in the as-built report`
      : 'no ring logged yet');
  };
  let ringsSince = 0;
  const fetchRings = tn.latestOnly(
    // Every ring of the window (not downsampled: at most one a minute).
    () => tn.json(`${api}/estimates?engine=rings&from=${ringsSince}&max_points=10000`),
    showRings,
    (e) => {
      ringsFor = null; // asked again at the next poll
      tn.setText(document.getElementById('ring-log-note'), `the ring log: ${e.message}`);
    },
  );
  const watchRings = (status) => {
    const newest = status.latest && status.latest.rings;
    if (!newest || newest.t === ringsFor) return;
    ringsFor = newest.t;
    // A week back holds the last ten rings of any drive that builds one
    // a day or more.
    ringsSince = newest.t - 7 * 86400;
    fetchRings();
  };
  const poll = tn.latestOnly(() => tn.json(api), (status) => { show(status); watchRings(status); },
    () => { /* the page's own polls report the link */ });
  poll();
  setInterval(poll, 2000);
})();
