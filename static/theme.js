// Before the first paint (loaded, not deferred, in the head), so the page
// never flashes the other theme: the stored choice of the ◐ button, else
// the system's preference. A file of its own: the pages' Content-Security-
// Policy allows no inline script.
'use strict';

(function () {
  var t = null;
  try { t = localStorage.getItem('tunnelnav-theme'); } catch (e) {}
  if (t !== 'light' && t !== 'dark') {
    t = matchMedia('(prefers-color-scheme: dark)').matches ? 'dark' : 'light';
  }
  document.documentElement.dataset.theme = t;
})();
