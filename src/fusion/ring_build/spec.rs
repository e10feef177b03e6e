//! A machine's segmental lining: universal tapered rings, their key
//! positions and the tail clearance they must keep (`"rings"` in the
//! machine's declaration).

use serde::{Deserialize, Serialize};

fn default_clearance_weight() -> f64 {
    1.0
}

/// Universal tapered rings and the gap to the shield's tail skin.
///
/// The key position `k` (0 to `key_positions` − 1) turns the ring so that
/// its widest point, and its key segment, sit at k·360°/`key_positions`
/// clockwise from the top, looking forward; the ring then turns the
/// lining away from that side by `taper_mm`/`diameter_m`. A manufacturer
/// whose taper sits elsewhere against the key numbers its positions so.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RingSpec {
    /// Widest less narrowest width of a ring, mm (the taper across its
    /// diameter).
    pub taper_mm: f64,
    /// Outer diameter of a ring, m.
    pub diameter_m: f64,
    /// Width of a ring on its centre line, m.
    pub width_m: f64,
    /// Key positions around the ring.
    pub key_positions: u32,
    /// Key positions never to be built (a key at the invert, say).
    #[serde(default)]
    pub forbidden_keys: Vec<u32>,
    /// The gap between the tail skin and a ring centred in it, mm.
    pub nominal_clearance_mm: f64,
    /// The least gap a ring may be given, mm.
    pub min_clearance_mm: f64,
    /// From the tail skin's end (the machine's declared rear point) to
    /// the newest ring's front face once it is built, m: the lining inside
    /// the tail; two ring widths when not declared. Longer than a ring, so
    /// that a ring stays in the tail after the push that follows its build.
    #[serde(default)]
    pub overlap_m: Option<f64>,
    /// The plan's trade-off: a millimetre of clearance off nominal costs
    /// this many times a millimetre of the built axis off the target
    /// curve (both squared).
    #[serde(default = "default_clearance_weight")]
    pub clearance_weight: f64,
}

impl RingSpec {
    /// Checks the values; the message names the field.
    pub fn check(&self) -> Result<(), String> {
        let within = |name: &str, v: f64, min: f64, max: f64| {
            if v.is_finite() && v >= min && v <= max {
                Ok(())
            } else {
                Err(format!(
                    "`rings.{name}` must be from {min} to {max}, not {v}"
                ))
            }
        };
        within("taper_mm", self.taper_mm, 0.0, 500.0)?;
        within("diameter_m", self.diameter_m, 0.5, 25.0)?;
        within("width_m", self.width_m, 0.3, 5.0)?;
        within(
            "nominal_clearance_mm",
            self.nominal_clearance_mm,
            1.0,
            500.0,
        )?;
        within(
            "min_clearance_mm",
            self.min_clearance_mm,
            0.0,
            self.nominal_clearance_mm,
        )?;
        within("clearance_weight", self.clearance_weight, 0.0, 1.0e6)?;
        if let Some(overlap) = self.overlap_m {
            within("overlap_m", overlap, self.width_m, 20.0)?;
        }
        if !(2..=64).contains(&self.key_positions) {
            return Err(format!(
                "`rings.key_positions` must be from 2 to 64, not {}",
                self.key_positions
            ));
        }
        for (i, &key) in self.forbidden_keys.iter().enumerate() {
            if key >= self.key_positions {
                return Err(format!(
                    "`rings.forbidden_keys[{i}]` is {key}: key positions are 0 to {}",
                    self.key_positions - 1
                ));
            }
            if self.forbidden_keys[..i].contains(&key) {
                return Err(format!("`rings.forbidden_keys` names {key} twice"));
            }
        }
        // Two allowed keys at least: the joints of consecutive rings must
        // not line up, so one key cannot follow itself.
        if self.allowed_keys().count() < 2 {
            return Err("`rings.forbidden_keys` must leave at least two key positions".into());
        }
        Ok(())
    }

    /// The key positions that may be built, ascending.
    pub fn allowed_keys(&self) -> impl Iterator<Item = u32> + '_ {
        (0..self.key_positions).filter(|k| !self.forbidden_keys.contains(k))
    }

    /// The ring's turn at full taper, rad: taper over diameter.
    pub fn taper_rad(&self) -> f64 {
        self.taper_mm / 1000.0 / self.diameter_m
    }

    /// Where key position `key` puts the widest point, rad clockwise from
    /// the top, looking forward.
    pub fn key_angle_rad(&self, key: u32) -> f64 {
        f64::from(key) * std::f64::consts::TAU / f64::from(self.key_positions)
    }

    /// From the tail's end to the newest ring's front face, m.
    pub fn overlap_m(&self) -> f64 {
        self.overlap_m.unwrap_or(2.0 * self.width_m)
    }

    /// Whether rings of keys `a` and `b` built one after the other have
    /// their longitudinal joints in line: the same key position.
    pub fn joints_aligned(a: u32, b: u32) -> bool {
        a == b
    }
}
