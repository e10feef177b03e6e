// Fleet overview: polls /api/v1/machines every second and fills the cards
// the server rendered; on an office, /api/v1/sites every 2 s for each
// site's link above its machines.
'use strict';

(function () {
  // Seconds (server clock) since a machine's newest reading before it is
  // marked stale, then offline.
  const STALE_S = 30, OFFLINE_S = 600;
  // Card values older than this say how old.
  const AGE_SHOWN_S = 10;
  const cards = new Map();
  document.querySelectorAll('.machine-card').forEach((card) => {
    const fields = {};
    card.querySelectorAll('[data-field]').forEach((el) => { fields[el.dataset.field] = el; });
    cards.set(card.dataset.machine, fields);
  });

  // Each engine's rows, from its script (tn.registerEngine), in the
  // order the server lists the machine's engines. An estimate that is
  // lost or too old is never shown as live: its values struck and greyed,
  // with why and how old.
  const fresh = tn.freshness(STALE_S);
  function figures(machine, latest, now) {
    const rows = [];
    for (const [name, estimate] of Object.entries(latest)) {
      const engine = tn.engines[name];
      if (!engine || !engine.card) continue;
      const judged = fresh.judge(`${machine}/${name}`, estimate, now);
      const note = tn.trustNote(estimate, judged);
      // A value more than a few seconds old carries its age even while
      // still current (a laser position between samples).
      const age = !note && judged.age > AGE_SHOWN_S
        ? ` <span class="age-note">${tn.duration(judged.age)} ago</span>` : '';
      for (const [k, v] of engine.card(estimate)) {
        rows.push([k, note
          ? `<span class="${judged.notLive ? 'not-live' : 'degraded'}">${v}</span> <span class="trust-note">${note}</span>`
          : `${v}${age}`]);
      }
    }
    return rows;
  }

  function render(card, m, now) {
    const age = typeof m.last_reading_t === 'number' ? now - m.last_reading_t : null;
    let [state, cls] = ['no data', ''];
    if (age !== null) {
      if (age <= STALE_S) [state, cls] = ['live', 'ok'];
      else if (age <= OFFLINE_S) [state, cls] = [`stale ${tn.duration(age)}`, 'warn'];
      else [state, cls] = [`offline ${tn.duration(age)}`, 'bad'];
    }
    tn.setText(card.state, state);
    card.state.className = `badge ${cls}`;

    const html = figures(m.machine, m.latest || {}, now)
      .map(([k, v]) => `<dt>${k}</dt><dd>${v}</dd>`).join('');
    if (card.figures.innerHTML !== html) card.figures.innerHTML = html;

    let laser = '\u00a0', laserCls = '';
    if (m.laser) {
      if (m.laser.dropout) {
        laser = `LASER DROPOUT · out for ${tn.duration(m.laser.age_s + (now - m.laser.t))}`;
        laserCls = 'bad';
      } else if (m.laser.ok) {
        laser = 'laser OK';
        laserCls = 'ok';
      } else {
        laser = 'no laser sample yet';
      }
    }
    tn.setText(card.laser, laser);
    card.laser.className = `laser-line ${laserCls}`;

    const sensors = Object.entries(m.sensors || {})
      .map(([name, s]) => `<li>${name}: ${tn.duration(now - s.last_t)} ago</li>`).join('');
    if (card.sensors.innerHTML !== sensors) card.sensors.innerHTML = sensors;
  }

  const poll = tn.latestOnly(() => tn.json('/api/v1/machines'), (body) => {
    tn.clock.sync(body.server_t, body.clock_rate);
    tn.link.ok('fleet');
    const ids = body.machines.map((m) => m.machine);
    if (ids.length !== cards.size || ids.some((id) => !cards.has(id))) {
      // Machines were declared or removed: the server renders the new set.
      location.reload();
      return;
    }
    for (const m of body.machines) render(cards.get(m.machine), m, body.server_t);
  }, (e) => {
    tn.link.failed('fleet', e.message);
    // Nothing on the cards may still say live.
    for (const card of cards.values()) {
      tn.setText(card.state, 'no connection');
      card.state.className = 'badge';
    }
  });

  poll();
  setInterval(poll, 1000);

  // An office: each site's link above its machines, from /api/v1/sites.
  const sites = new Map();
  document.querySelectorAll('.site-group[data-site]').forEach((group) => {
    const fields = {};
    group.querySelectorAll('[data-site-field]').forEach((el) => { fields[el.dataset.siteField] = el; });
    sites.set(group.dataset.site, fields);
  });
  if (sites.size === 0) return;
  const pollSites = tn.latestOnly(() => tn.json('/api/v1/sites'), (body) => {
    const now = tn.clock.now();
    for (const s of body.sites) {
      const fields = sites.get(s.site);
      if (!fields) continue;
      const [link, cls] = s.connected
        ? [s.alarm ? 'link up · behind' : 'link up', s.alarm ? 'warn' : 'ok']
        : ['LINK DOWN', 'bad'];
      tn.setText(fields.link, link);
      fields.link.className = `badge ${cls}`;
      const contact = `last contact ${tn.duration(Math.max(0, now - s.last_contact_t))} ago`;
      const backlog = s.backlog_items === 0
        ? 'nothing unsent'
        : `${s.backlog_readings.toLocaleString('en')} readings unsent, oldest ${tn.duration(s.oldest_unsent_s)}`;
      tn.setText(fields.backlog, `${backlog} · ${contact}`);
    }
  }, () => {
    for (const fields of sites.values()) {
      tn.setText(fields.link, 'no connection');
      fields.link.className = 'badge';
    }
  });
  pollSites();
  setInterval(pollSites, 2000);
})();
