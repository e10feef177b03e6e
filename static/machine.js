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
  const poll = tn.latestOnly(() => tn.json(api), show, () => { /* the page's own polls report the link */ });
  poll();
  setInterval(poll, 2000);
})();
