// The `dta` stage's part of a machine page and its fleet card rows.
'use strict';

tn.registerEngine('dta', {
  card(d) {
    return [['deviation', `front H ${tn.fixed(d.front.horizontal_mm, 0)} V ${tn.fixed(d.front.vertical_mm, 0)} mm`]];
  },
  page() {},
});
