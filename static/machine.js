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
})();
