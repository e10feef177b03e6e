//! Alarm rules: pure functions of a machine's readings, estimates and the
//! server clock's ticks, deciding when an alarm is raised and when it
//! clears (the shell stores, acknowledges, notifies).
//!
//! The rules read the [`Signals`] each stream's estimates tell
//! (`src/fusion/descriptor.rs`), not the streams themselves: today
//! `attitude` tells the laser and its pitch σ, `zupt` its navigation
//! solution, `dta` the deviation. Where several of a machine's streams
//! tell one signal, the first in registry order is watched. Kinds:
//! - `deviation`: the deviation beyond the warn or alarm tolerance;
//! - `laser_dropout`: the laser sample older than a limit;
//! - `stale_sensor`: a sensor silent for more than N of its own periods,
//!   learned from its readings ([`period`]); not the laser, whose beam is
//!   lost routinely for minutes (`laser_dropout` is its rule);
//! - `ins_uncertainty`: the inertial position's horizontal 1σ above a limit;
//! - `attitude_uncertainty`: the pitch 1σ above a limit (a long laser
//!   dropout, a roll the model has not seen: steer with care);
//! - `engine_reset`: an INS lost its solution and re-aligns (the engine is
//!   the alarm's subject);
//! - `steering_infeasible`: no correction curve within the machine's
//!   minimum radius reaches the axis within 500 m (`steer`);
//! - `integrity`: an engine's estimates not `ok` (warn: degraded or lost
//!   for a while; alarm: lost), the engine the alarm's subject. Stages
//!   inherit their source's integrity, so only engines are watched: one
//!   fault, one alarm.
//!
//! Values at a limit do not flap: a limit must be undercut by a band (for
//! a deviation, at least its 2σ) before it counts as cleared, a condition
//! must hold (or be gone) for a minimum time, and a raised alarm of a noisy
//! input stays raised for a minimum hold ([`debounce`]). A deviation whose
//! source is lost is not judged: its alarm stays as it was. The server's
//! own downtime is not a sensor's silence ([`AlarmRules::resumed`]).

pub mod debounce;
pub mod period;

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use self::debounce::{Debounced, Edge, Hysteresis, Timing};
use self::period::LearnedPeriod;
use super::StreamKind;
use super::descriptor::{DeviationSignal, Navigation, SignalKind, Signals};
use super::dta::Tolerances;
use super::estimate::EngineOutput;
use super::integrity::{Integrity, IntegrityLevel, IntegrityReason};
use super::reading::{Reading, SensorKind};

/// What an alarm is about.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Serialize,
    Deserialize,
    utoipa::ToSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum AlarmKind {
    Deviation,
    LaserDropout,
    StaleSensor,
    InsUncertainty,
    EngineReset,
    AttitudeUncertainty,
    /// No correction curve within the minimum radius reaches the axis.
    SteeringInfeasible,
    /// An office's: the link to the machine's site has been down, or its
    /// backlog unsent, longer than the office allows (the server raises
    /// it, not the machine's rules).
    SiteLink,
    /// An engine's estimates degraded or lost (the engine the subject).
    Integrity,
    /// An office's: a site forwarded rows at or below the machine's mark
    /// that the office does not hold (a forged or foreign sequence moved
    /// the mark); refused until an admin sets the mark back (the server
    /// raises it).
    ForwardRefused,
}

impl AlarmKind {
    /// Every kind.
    pub const ALL: [AlarmKind; 10] = [
        AlarmKind::Deviation,
        AlarmKind::LaserDropout,
        AlarmKind::StaleSensor,
        AlarmKind::InsUncertainty,
        AlarmKind::EngineReset,
        AlarmKind::AttitudeUncertainty,
        AlarmKind::SteeringInfeasible,
        AlarmKind::SiteLink,
        AlarmKind::Integrity,
        AlarmKind::ForwardRefused,
    ];

    /// The kind of a protocol name.
    pub fn from_name(name: &str) -> Option<AlarmKind> {
        AlarmKind::ALL.into_iter().find(|k| k.as_str() == name)
    }

    /// The protocol's name.
    pub fn as_str(self) -> &'static str {
        match self {
            AlarmKind::Deviation => "deviation",
            AlarmKind::LaserDropout => "laser_dropout",
            AlarmKind::StaleSensor => "stale_sensor",
            AlarmKind::InsUncertainty => "ins_uncertainty",
            AlarmKind::EngineReset => "engine_reset",
            AlarmKind::AttitudeUncertainty => "attitude_uncertainty",
            AlarmKind::SteeringInfeasible => "steering_infeasible",
            AlarmKind::SiteLink => "site_link",
            AlarmKind::Integrity => "integrity",
            AlarmKind::ForwardRefused => "forward_refused",
        }
    }
}

/// How bad.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Serialize,
    Deserialize,
    utoipa::ToSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Severity {
    Warn,
    Alarm,
}

impl Severity {
    /// Both, the milder first.
    pub const ALL: [Severity; 2] = [Severity::Warn, Severity::Alarm];

    /// The severity of a protocol name.
    pub fn from_name(name: &str) -> Option<Severity> {
        Severity::ALL.into_iter().find(|s| s.as_str() == name)
    }

    /// The protocol's name.
    pub fn as_str(self) -> &'static str {
        match self {
            Severity::Warn => "warn",
            Severity::Alarm => "alarm",
        }
    }
}

/// One alarm of a machine: its kind, severity and what it concerns (a
/// sensor's name for `stale_sensor`, else empty). At most one alarm per
/// key is active at a time.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct AlarmKey {
    pub kind: AlarmKind,
    pub severity: Severity,
    pub subject: String,
}

/// An alarm raised or cleared.
#[derive(Debug, Clone, PartialEq)]
pub struct Transition {
    pub key: AlarmKey,
    /// True: raised; false: cleared.
    pub raised: bool,
    /// When the condition began (raised) or ended (cleared), s.
    pub t: f64,
    /// For the operator: what is wrong (raised) or that it is over.
    pub message: String,
}

/// What an active alarm's quantity reads now (its message keeps the value
/// at the raise): "rear vertical +38 mm", "lost (tilt_disagrees)".
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct AlarmNow {
    /// When it was judged last, s (the data's time, or the server clock's
    /// for a silent sensor).
    pub t: f64,
    pub value: String,
}

/// The rules' settings (a machine declaration's `alarms`), with defaults
/// that need no site tuning: the periods are learned, the tolerances
/// are the machine's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct AlarmConfig {
    /// A condition must hold this long before it is raised, and be gone
    /// this long before it clears, s.
    pub min_duration_s: f64,
    /// Below a limit by this fraction of it before a value counts as back.
    pub hysteresis_fraction: f64,
    /// Laser sample older than this: `laser_dropout` warn, then alarm, s.
    pub laser_dropout_warn_s: f64,
    pub laser_dropout_alarm_s: f64,
    /// A sensor silent for this many of its periods (and at least
    /// `stale_min_s`): `stale_sensor`.
    pub stale_periods: f64,
    pub stale_min_s: f64,
    /// The INS's horizontal position 1σ above this: `ins_uncertainty`, mm.
    pub ins_sigma_warn_mm: f64,
    pub ins_sigma_alarm_mm: f64,
    /// The `attitude` pitch 1σ above this: `attitude_uncertainty`, degrees.
    pub attitude_sigma_warn_deg: f64,
    pub attitude_sigma_alarm_deg: f64,
    /// A raised `deviation`, `ins_uncertainty`, `attitude_uncertainty` or
    /// `integrity` alarm stays raised at least this long from its onset,
    /// s: their inputs are noisy, and one episode at a limit raises once.
    pub min_hold_s: f64,
    /// An engine's estimates degraded (or lost) this long: `integrity`
    /// warn, s.
    pub integrity_degraded_warn_s: f64,
    /// An engine's estimates lost this long: `integrity` alarm, s.
    pub integrity_lost_alarm_s: f64,
}

impl Default for AlarmConfig {
    fn default() -> Self {
        AlarmConfig {
            min_duration_s: 10.0,
            hysteresis_fraction: 0.1,
            laser_dropout_warn_s: 300.0,
            laser_dropout_alarm_s: 1800.0,
            stale_periods: 5.0,
            stale_min_s: 10.0,
            ins_sigma_warn_mm: 100.0,
            ins_sigma_alarm_mm: 250.0,
            attitude_sigma_warn_deg: 0.05,
            attitude_sigma_alarm_deg: 0.1,
            min_hold_s: 60.0,
            integrity_degraded_warn_s: 10.0,
            integrity_lost_alarm_s: 0.0,
        }
    }
}

impl AlarmConfig {
    /// What is wrong with the settings, if anything.
    pub fn validate(&self) -> Result<(), String> {
        let fields = [
            ("min_duration_s", self.min_duration_s),
            ("hysteresis_fraction", self.hysteresis_fraction),
            ("laser_dropout_warn_s", self.laser_dropout_warn_s),
            ("laser_dropout_alarm_s", self.laser_dropout_alarm_s),
            ("stale_periods", self.stale_periods),
            ("stale_min_s", self.stale_min_s),
            ("ins_sigma_warn_mm", self.ins_sigma_warn_mm),
            ("ins_sigma_alarm_mm", self.ins_sigma_alarm_mm),
            ("attitude_sigma_warn_deg", self.attitude_sigma_warn_deg),
            ("attitude_sigma_alarm_deg", self.attitude_sigma_alarm_deg),
            ("min_hold_s", self.min_hold_s),
            ("integrity_degraded_warn_s", self.integrity_degraded_warn_s),
            ("integrity_lost_alarm_s", self.integrity_lost_alarm_s),
        ];
        for (name, value) in fields {
            if !(value.is_finite() && value >= 0.0) {
                return Err(format!("alarms.{name} = {value} is not a number ≥ 0"));
            }
        }
        if self.hysteresis_fraction >= 1.0 {
            return Err("alarms.hysteresis_fraction must be below 1".into());
        }
        if self.laser_dropout_alarm_s < self.laser_dropout_warn_s
            || self.ins_sigma_alarm_mm < self.ins_sigma_warn_mm
            || self.attitude_sigma_alarm_deg < self.attitude_sigma_warn_deg
        {
            return Err("alarms: each alarm limit must be at or above its warn limit".into());
        }
        if self.stale_periods < 1.0 {
            return Err("alarms.stale_periods must be at least 1".into());
        }
        Ok(())
    }
}

/// A limit-crossing rule's state: whether the value is beyond the limit
/// (with hysteresis) and the debounced alarm.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
struct Level {
    beyond: bool,
    alarm: Debounced,
}

impl Level {
    fn update(&mut self, t: f64, value: f64, limit: Hysteresis, timing: Timing) -> Option<Edge> {
        self.beyond = limit.exceeded(value, self.beyond);
        self.alarm.update_timed(t, self.beyond, timing)
    }
}

/// What the `integrity` rule remembers of one engine.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
struct IntegrityWatch {
    /// The engine has vouched for an estimate (been `ok`) since the rules
    /// began: its first alignment is not a fault.
    vouched: bool,
    /// Degraded or lost (warn), lost (alarm).
    warn: Debounced,
    alarm: Debounced,
}

/// What the rules remember (part of the machine's snapshot).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AlarmState {
    /// Deviation, laser dropout, INS σ, attitude σ: [warn, alarm] each.
    deviation: [Level; 2],
    laser: [Level; 2],
    ins: [Level; 2],
    #[serde(default)]
    attitude: [Level; 2],
    reset: Debounced,
    #[serde(default)]
    steering: Debounced,
    was_aligned: bool,
    sensors: BTreeMap<SensorKind, (LearnedPeriod, Debounced)>,
    #[serde(default)]
    integrity: BTreeMap<StreamKind, IntegrityWatch>,
}

/// The rules of one machine.
#[derive(Debug, Clone, PartialEq)]
pub struct AlarmRules {
    config: AlarmConfig,
    tolerances: Option<Tolerances>,
    state: AlarmState,
    /// The stream each signal is watched from: of the machine's streams
    /// that tell it, the first in registry order.
    watched: BTreeMap<SignalKind, StreamKind>,
    /// When the server (re)started running the rules, by its clock: a
    /// sensor's silence is counted from here at the earliest.
    resumed_t: Option<f64>,
    /// What each active alarm's quantity reads now, by kind and subject
    /// (both severities read the same quantity). Not snapshotted: it is
    /// judged again at the next estimate.
    now: BTreeMap<(AlarmKind, String), AlarmNow>,
}

const SEVERITIES: [Severity; 2] = [Severity::Warn, Severity::Alarm];

/// A limit in time as an operator reads it: seconds below two minutes,
/// else minutes.
fn span(seconds: f64) -> String {
    if seconds < 120.0 {
        format!("{seconds:.0} s")
    } else {
        format!("{:.0} min", seconds / 60.0)
    }
}

fn key(kind: AlarmKind, severity: Severity, subject: &str) -> AlarmKey {
    AlarmKey {
        kind,
        severity,
        subject: subject.to_string(),
    }
}

fn push(out: &mut Vec<Transition>, key: AlarmKey, edge: Edge, raised: String, cleared: String) {
    out.push(match edge {
        Edge::Raised { onset_t } => Transition {
            key,
            raised: true,
            t: onset_t,
            message: raised,
        },
        Edge::Cleared { gone_t } => Transition {
            key,
            raised: false,
            t: gone_t,
            message: cleared,
        },
    });
}

impl AlarmRules {
    /// Rules with `config` for a machine with `tolerances` (none: no
    /// deviation alarms) whose engines and stages make `streams`, from a
    /// fresh state or a snapshot's.
    pub fn new(
        config: AlarmConfig,
        tolerances: Option<Tolerances>,
        streams: &[StreamKind],
        state: AlarmState,
    ) -> AlarmRules {
        let mut sorted = streams.to_vec();
        sorted.sort();
        let mut watched = BTreeMap::new();
        for stream in sorted {
            for &signal in stream.signals() {
                watched.entry(signal).or_insert(stream);
            }
        }
        AlarmRules {
            config,
            tolerances,
            state,
            watched,
            resumed_t: None,
            now: BTreeMap::new(),
        }
    }

    /// What each active alarm's quantity reads now, by kind and subject.
    pub fn now(&self) -> &BTreeMap<(AlarmKind, String), AlarmNow> {
        &self.now
    }

    /// Keeps what the alarm of `kind` about `subject` reads at `t` while
    /// it is `active` (formatted only then), forgets it once cleared.
    fn note(
        &mut self,
        kind: AlarmKind,
        subject: &str,
        t: f64,
        active: bool,
        value: impl FnOnce() -> String,
    ) {
        if active {
            let key = (kind, subject.to_string());
            self.now.insert(key, AlarmNow { t, value: value() });
        } else if !self.now.is_empty() {
            self.now.retain(|(k, s), _| !(*k == kind && s == subject));
        }
    }

    /// The server runs the rules again at `now_t` (a start, a recovery):
    /// the time it was down is not its sensors' silence.
    pub fn resumed(&mut self, now_t: f64) {
        self.resumed_t = Some(now_t);
    }

    /// When the server last resumed the rules, if it told.
    pub fn resumed_t(&self) -> Option<f64> {
        self.resumed_t
    }

    /// The timing of a rule whose input is noisy.
    fn held(&self, raise_s: f64) -> Timing {
        Timing {
            raise_s,
            clear_s: self.config.min_duration_s,
            hold_s: self.config.min_hold_s,
        }
    }

    /// The state to snapshot.
    pub fn state(&self) -> &AlarmState {
        &self.state
    }

    /// A reading: its sensor's period and newest time; a stale sensor
    /// that speaks again clears (after the minimum time's readings).
    pub fn reading(&mut self, reading: &Reading, out: &mut Vec<Transition>) {
        let sensor = reading.sensor();
        let (period, stale) = self.state.sensors.entry(sensor).or_default();
        period.add(reading.t);
        if let Some(edge) = stale.update(reading.t, false, 0.0) {
            push(
                out,
                key(AlarmKind::StaleSensor, Severity::Alarm, sensor.as_str()),
                edge,
                String::new(),
                format!("{sensor} readings again"),
            );
        }
        let active = stale.active;
        self.note(
            AlarmKind::StaleSensor,
            sensor.as_str(),
            reading.t,
            active,
            || "reading again".into(),
        );
    }

    /// The server clock at `now_t`: sensors silent for too long.
    pub fn tick(&mut self, now_t: f64, out: &mut Vec<Transition>) {
        let c = self.config;
        let mut silent = Vec::new();
        for (sensor, (period, stale)) in &mut self.state.sensors {
            // The laser's beam is lost routinely (`laser_dropout`); a ring
            // is closed when it is built, not on a period.
            if matches!(sensor, SensorKind::Laser | SensorKind::Advance) {
                continue;
            }
            let (Some(last_t), Some(period_s)) = (period.last_t, period.period_s()) else {
                continue;
            };
            let limit_s = (c.stale_periods * period_s).max(c.stale_min_s);
            let silent_s = now_t - last_t;
            let silent_from_t = last_t.max(self.resumed_t.unwrap_or(last_t));
            if now_t - silent_from_t > limit_s
                && let Some(edge) = stale.update(silent_from_t + limit_s, true, 0.0)
            {
                push(
                    out,
                    key(AlarmKind::StaleSensor, Severity::Alarm, sensor.as_str()),
                    edge,
                    format!(
                        "no {sensor} reading for {silent_s:.0} s (it reads every {period_s:.2} s)"
                    ),
                    String::new(),
                );
            }
            if stale.active {
                silent.push((*sensor, silent_s));
            }
        }
        for (sensor, silent_s) in silent {
            self.note(AlarmKind::StaleSensor, sensor.as_str(), now_t, true, || {
                format!("silent for {}", span(silent_s))
            });
        }
    }

    /// An engine's or stage's estimate: the rules read its
    /// [`Signals`], whichever stream tells them.
    pub fn estimate(&mut self, estimate: &EngineOutput, out: &mut Vec<Transition>) {
        self.signals(
            estimate.t,
            estimate.values.stream(),
            estimate.integrity,
            &estimate.values.signals(),
            out,
        );
    }

    /// The signals of an estimate of `stream` at `t` with `integrity`
    /// (those it is watched for).
    pub fn signals(
        &mut self,
        t: f64,
        stream: StreamKind,
        integrity: Integrity,
        signals: &Signals,
        out: &mut Vec<Transition>,
    ) {
        if stream.engine().is_some() {
            self.integrity(t, stream, integrity, out);
        }
        let watched = |kind| self.watched.get(&kind) == Some(&stream);
        let deviation = signals.deviation.filter(|_| watched(SignalKind::Deviation));
        let pitch_sigma_deg = signals
            .pitch_sigma_deg
            .filter(|_| watched(SignalKind::PitchSigma));
        let laser = signals.laser.filter(|_| watched(SignalKind::Laser));
        let navigation = signals
            .navigation
            .filter(|_| watched(SignalKind::Navigation));
        let steering_feasible = signals
            .steering_feasible
            .filter(|_| watched(SignalKind::Steering));
        // A lost source's deviation is not judged: its alarm stays as it
        // was until a position can be vouched for again.
        if let Some(deviation) = &deviation
            && integrity.level != IntegrityLevel::Lost
        {
            self.deviation(t, deviation, out);
        }
        if let Some(sigma_deg) = pitch_sigma_deg {
            self.attitude_uncertainty(t, sigma_deg, out);
        }
        if let Some(age_s) = laser.and_then(|laser| laser.age_s) {
            self.laser_dropout(t, age_s, out);
        }
        if let Some(navigation) = navigation {
            self.navigation(t, stream, navigation, out);
        }
        if let Some(feasible) = steering_feasible {
            self.steering(t, feasible, out);
        }
    }

    /// `integrity` of an engine: warn while not `ok` for
    /// `integrity_degraded_warn_s`, alarm while lost for
    /// `integrity_lost_alarm_s`. Unaligned or unverified before the engine
    /// was ever `ok` (its first alignment, its first checks) is not a fault.
    fn integrity(
        &mut self,
        t: f64,
        stream: StreamKind,
        integrity: Integrity,
        out: &mut Vec<Transition>,
    ) {
        let c = self.config;
        let warn_timing = self.held(c.integrity_degraded_warn_s);
        let alarm_timing = self.held(c.integrity_lost_alarm_s);
        let watch = self.state.integrity.entry(stream).or_default();
        watch.vouched |= integrity.is_ok();
        let first_alignment = !watch.vouched
            && matches!(
                integrity.reason,
                Some(IntegrityReason::Unaligned | IntegrityReason::Unverified)
            );
        let not_ok = !integrity.is_ok() && !first_alignment;
        let lost = integrity.level == IntegrityLevel::Lost && !first_alignment;
        let reason = integrity.reason.map_or("", IntegrityReason::as_str);
        let name = stream.as_str();
        for (severity, debounced, holds, timing) in [
            (Severity::Warn, &mut watch.warn, not_ok, warn_timing),
            (Severity::Alarm, &mut watch.alarm, lost, alarm_timing),
        ] {
            if let Some(edge) = debounced.update_timed(t, holds, timing) {
                let raised = match severity {
                    Severity::Warn => format!(
                        "{name} estimates {} ({reason}) for over {}: their σ is widened, or they cannot be vouched for",
                        integrity.level.as_str(),
                        span(timing.raise_s)
                    ),
                    Severity::Alarm => format!(
                        "{name} estimates lost ({reason}): the engine cannot vouch for its values; do not steer by them"
                    ),
                };
                push(
                    out,
                    key(AlarmKind::Integrity, severity, name),
                    edge,
                    raised,
                    format!("{name} estimates vouched for again"),
                );
            }
        }
        let active = watch.warn.active || watch.alarm.active;
        self.note(AlarmKind::Integrity, name, t, active, || {
            match integrity.reason {
                Some(reason) => format!("{} ({})", integrity.level.as_str(), reason.as_str()),
                None => integrity.level.as_str().to_string(),
            }
        });
    }

    /// `steering_infeasible` while no curve reaches the axis (for the
    /// minimum time, as a deviation).
    fn steering(&mut self, t: f64, feasible: bool, out: &mut Vec<Transition>) {
        let min_s = self.config.min_duration_s;
        if let Some(edge) = self.state.steering.update(t, !feasible, min_s) {
            push(
                out,
                key(AlarmKind::SteeringInfeasible, Severity::Alarm, ""),
                edge,
                "no correction curve within the machine's minimum radius reaches the design axis within 500 m".into(),
                "a correction curve back to the axis again".into(),
            );
        }
        let active = self.state.steering.active;
        self.note(AlarmKind::SteeringInfeasible, "", t, active, || {
            if feasible {
                "a curve reaches the axis"
            } else {
                "no curve reaches the axis"
            }
            .into()
        });
    }

    fn laser_dropout(&mut self, t: f64, age_s: f64, out: &mut Vec<Transition>) {
        let c = self.config;
        let limits = [c.laser_dropout_warn_s, c.laser_dropout_alarm_s];
        for (i, severity) in SEVERITIES.into_iter().enumerate() {
            // Time is the quantity itself: no minimum on top.
            let limit = Hysteresis {
                limit: limits[i],
                band: 0.0,
            };
            if let Some(edge) = self.state.laser[i].update(t, age_s, limit, Timing::symmetric(0.0))
            {
                push(
                    out,
                    key(AlarmKind::LaserDropout, severity, ""),
                    edge,
                    format!("no laser sample for over {}", span(limits[i])),
                    "laser samples again".into(),
                );
            }
        }
        let active = self.state.laser.iter().any(|l| l.alarm.active);
        self.note(AlarmKind::LaserDropout, "", t, active, || {
            format!("last laser sample {} ago", span(age_s))
        });
    }

    /// `ins_uncertainty` while aligned; `engine_reset` (about `stream`)
    /// from losing the solution until aligned again.
    fn navigation(
        &mut self,
        t: f64,
        stream: StreamKind,
        navigation: Navigation,
        out: &mut Vec<Transition>,
    ) {
        let c = self.config;
        let aligned = match navigation {
            Navigation::Aligned {
                horizontal_sigma_mm: sigma_mm,
            } => {
                let limits = [c.ins_sigma_warn_mm, c.ins_sigma_alarm_mm];
                for (i, severity) in SEVERITIES.into_iter().enumerate() {
                    let limit = Hysteresis {
                        limit: limits[i],
                        band: c.hysteresis_fraction * limits[i],
                    };
                    let timing = self.held(c.min_duration_s);
                    if let Some(edge) = self.state.ins[i].update(t, sigma_mm, limit, timing) {
                        push(
                            out,
                            key(AlarmKind::InsUncertainty, severity, ""),
                            edge,
                            format!(
                                "INS horizontal position 1σ {sigma_mm:.0} mm, over {:.0} mm: a check survey is due",
                                limits[i]
                            ),
                            format!("INS horizontal position 1σ back under {:.0} mm", limits[i]),
                        );
                    }
                }
                let active = self.state.ins.iter().any(|l| l.alarm.active);
                self.note(AlarmKind::InsUncertainty, "", t, active, || {
                    format!("1σ {sigma_mm:.0} mm")
                });
                true
            }
            Navigation::Aligning => false,
        };
        let reset = self.state.was_aligned && !aligned;
        self.state.was_aligned = aligned;
        let holds = reset || (self.state.reset.active && !aligned);
        if let Some(edge) = self.state.reset.update(t, holds, 0.0) {
            push(
                out,
                key(AlarmKind::EngineReset, Severity::Warn, stream.as_str()),
                edge,
                "the INS lost its navigation solution and is re-aligning: positions restart".into(),
                "the INS is aligned again".into(),
            );
        }
        let active = self.state.reset.active;
        self.note(AlarmKind::EngineReset, stream.as_str(), t, active, || {
            if aligned { "aligned" } else { "re-aligning" }.into()
        });
    }

    fn attitude_uncertainty(&mut self, t: f64, sigma_deg: f64, out: &mut Vec<Transition>) {
        let c = self.config;
        let limits = [c.attitude_sigma_warn_deg, c.attitude_sigma_alarm_deg];
        for (i, severity) in SEVERITIES.into_iter().enumerate() {
            let limit = Hysteresis {
                limit: limits[i],
                band: c.hysteresis_fraction * limits[i],
            };
            let timing = self.held(c.min_duration_s);
            if let Some(edge) = self.state.attitude[i].update(t, sigma_deg, limit, timing) {
                push(
                    out,
                    key(AlarmKind::AttitudeUncertainty, severity, ""),
                    edge,
                    format!(
                        "pitch 1σ {sigma_deg:.3}°, over {:.3}°: steer with care (laser out, or a roll the model has not seen)",
                        limits[i]
                    ),
                    format!("pitch 1σ back under {:.3}°", limits[i]),
                );
            }
        }
        let active = self.state.attitude.iter().any(|l| l.alarm.active);
        self.note(AlarmKind::AttitudeUncertainty, "", t, active, || {
            format!("pitch 1σ {sigma_deg:.3}°")
        });
    }

    /// `deviation`: the worst of the four deviations against its own
    /// limit. Raised beyond a limit; back only below the limit less the
    /// larger of the hysteresis fraction and the deviation's 2σ (a noisy
    /// position hovering at a limit raises once; one whose 2σ is as wide
    /// as the limit stays raised until it narrows).
    fn deviation(&mut self, t: f64, d: &DeviationSignal, out: &mut Vec<Transition>) {
        let Some(tol) = self.tolerances else { return };
        let c = self.config;
        let timing = self.held(c.min_duration_s);
        // The worst against the warn limits, as the alarm reads now.
        let mut worst_now = String::new();
        let points = [
            ("front", d.front_mm, d.front_sigma_mm),
            ("rear", d.rear_mm, d.rear_sigma_mm),
        ];
        for (i, severity) in SEVERITIES.into_iter().enumerate() {
            let limit = |l: super::dta::Limits| if i == 0 { l.warn } else { l.alarm };
            let (h, v) = (limit(tol.horizontal_mm), limit(tol.vertical_mm));
            let was = self.state.deviation[i].beyond;
            // The worst of the four against its own limit, as a ratio;
            // beyond if any is past its limit (less its band, once beyond).
            let mut beyond = false;
            let mut worst = (0.0, String::new());
            for (name, p, sigma) in points {
                for (axis, value, sigma_mm, lim) in [
                    ("horizontal", p[0], sigma[0], h),
                    ("vertical", p[1], sigma[1], v),
                ] {
                    let band = Hysteresis {
                        limit: lim,
                        band: (c.hysteresis_fraction * lim).max(2.0 * sigma_mm),
                    };
                    beyond |= lim > 0.0 && band.exceeded(value.abs(), was);
                    let ratio = if lim > 0.0 { value.abs() / lim } else { 0.0 };
                    if ratio > worst.0 {
                        worst = (
                            ratio,
                            format!("{name} {axis} {value:+.0} mm (±{lim:.0} mm)"),
                        );
                    }
                }
            }
            let level = &mut self.state.deviation[i];
            level.beyond = beyond;
            if let Some(edge) = level.alarm.update_timed(t, beyond, timing) {
                let word = if i == 0 { "warn" } else { "alarm" };
                push(
                    out,
                    key(AlarmKind::Deviation, severity, ""),
                    edge,
                    format!(
                        "deviation from the design axis past the {word} tolerance: {}",
                        worst.1
                    ),
                    format!("deviation back within the {word} tolerance"),
                );
            }
            if i == 0 {
                worst_now = worst.1;
            }
        }
        let active = self.state.deviation.iter().any(|l| l.alarm.active);
        self.note(AlarmKind::Deviation, "", t, active, || worst_now);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::AttitudeEstimate;
    use crate::fusion::EstimateValues;
    use crate::fusion::dta::{DtaEstimate, DtaSource, Limits, PointDeviation};
    use crate::fusion::reading::SensorData;

    fn rules() -> AlarmRules {
        let tolerances = Tolerances {
            horizontal_mm: Limits {
                warn: 50.0,
                alarm: 100.0,
            },
            vertical_mm: Limits {
                warn: 30.0,
                alarm: 60.0,
            },
        };
        AlarmRules::new(
            AlarmConfig::default(),
            Some(tolerances),
            StreamKind::ALL,
            AlarmState::default(),
        )
    }

    fn dta(t: f64, front_h_mm: f64, rear_v_mm: f64) -> EngineOutput {
        let point = |h, v| PointDeviation {
            station_m: 10.0,
            horizontal_mm: h,
            vertical_mm: v,
            sigma_horizontal_mm: None,
            sigma_vertical_mm: None,
        };
        EngineOutput {
            integrity: crate::fusion::Integrity::OK,
            t,
            values: EstimateValues::Dta(DtaEstimate {
                source: DtaSource::Laser,
                station_m: 10.0,
                front: point(front_h_mm, 0.0),
                rear: point(0.0, rear_v_mm),
                tendency_horizontal_mm_per_m: 0.0,
                tendency_vertical_mm_per_m: 0.0,
                status: None,
            }),
        }
    }

    fn run(
        rules: &mut AlarmRules,
        outputs: impl IntoIterator<Item = EngineOutput>,
    ) -> Vec<Transition> {
        let mut out = Vec::new();
        for o in outputs {
            rules.estimate(&o, &mut out);
        }
        out
    }

    #[test]
    fn deviation_is_raised_after_the_minimum_time_holds_at_the_limit_and_clears() {
        let mut r = rules();
        // 40 mm for 10 s, then 55 mm from t = 10: warn raised at t = 20,
        // dated 10.
        let mut out = run(&mut r, (0..10).map(|i| dta(f64::from(i), 40.0, 0.0)));
        out.extend(run(&mut r, (10..=20).map(|i| dta(f64::from(i), 55.0, 0.0))));
        assert_eq!(out.len(), 1, "{out:?}");
        assert!(out[0].raised && out[0].t == 10.0);
        assert_eq!(out[0].key, key(AlarmKind::Deviation, Severity::Warn, ""));
        assert!(
            out[0]
                .message
                .contains("past the warn tolerance: front horizontal +55 mm (±50 mm)"),
            "{}",
            out[0].message
        );
        // Hovering 46–52 mm (above 45, the limit less its 10 %): no flapping.
        let hover = (21..60).map(|i| dta(f64::from(i), if i % 2 == 0 { 46.0 } else { 52.0 }, 0.0));
        assert!(run(&mut r, hover).is_empty());
        // Back to 40 mm at t = 60: cleared at t = 70, dated 60.
        let out = run(&mut r, (60..=70).map(|i| dta(f64::from(i), 40.0, 0.0)));
        assert_eq!(out.len(), 1, "{out:?}");
        assert!(!out[0].raised && out[0].t == 60.0);
        // The rear 70 mm low: beyond the vertical alarm limit (60): warn and
        // alarm both, once each.
        let out = run(&mut r, (71..=100).map(|i| dta(f64::from(i), 0.0, -70.0)));
        let raised: Vec<_> = out
            .iter()
            .filter(|t| t.raised)
            .map(|t| t.key.severity)
            .collect();
        assert_eq!(raised, [Severity::Warn, Severity::Alarm], "{out:?}");
        assert!(
            out[1].message.contains("rear vertical -70 mm (±60 mm)"),
            "{}",
            out[1].message
        );
    }

    #[test]
    fn an_active_alarm_says_what_its_quantity_reads_now_and_forgets_it_once_cleared() {
        let now = |r: &AlarmRules| r.now().get(&(AlarmKind::Deviation, String::new())).cloned();
        let mut r = rules();
        // Not raised: nothing to say.
        run(&mut r, (0..5).map(|i| dta(f64::from(i), 40.0, 0.0)));
        assert_eq!(now(&r), None);
        // Raised at +55 mm (at t = 15, dated 5), then the machine swings to
        // -47 mm: the message keeps +55, now says -47.
        let out = run(&mut r, (5..=15).map(|i| dta(f64::from(i), 55.0, 0.0)));
        assert!(out[0].message.contains("+55 mm"), "{}", out[0].message);
        run(&mut r, [dta(16.0, -47.0, 0.0)]);
        let reads = now(&r).expect("the raised deviation reads now");
        assert_eq!(reads.t, 16.0);
        assert_eq!(reads.value, "front horizontal -47 mm (±50 mm)");
        // Back to 10 mm from t = 70 (past the hold): cleared, forgotten.
        let out = run(&mut r, (70..=80).map(|i| dta(f64::from(i), 10.0, 0.0)));
        assert!(out.iter().any(|t| !t.raised), "{out:?}");
        assert_eq!(now(&r), None);
    }

    #[test]
    fn steering_infeasible_is_raised_once_held_and_cleared_once_a_curve_returns() {
        use crate::fusion::steer::{SteerEstimate, SteerPlane};
        let steer = |t: f64, feasible: bool| {
            let plane = SteerPlane {
                deviation_mm: 0.0,
                tendency_mm_per_m: 0.0,
                next_deviation_mm: None,
                stroke_difference_mm: None,
                curvature_per_m: None,
                articulation_deg: None,
                outside_warn: false,
                own_curvature_per_m: None,
            };
            EngineOutput {
                integrity: crate::fusion::Integrity::OK,
                t,
                values: EstimateValues::Steer(SteerEstimate {
                    station_m: 0.0,
                    feasible,
                    steps: None,
                    length_m: None,
                    horizontal: plane,
                    vertical: plane,
                    replanned: true,
                    words: String::new(),
                    groups: Vec::new(),
                    internal_station_m: 0.0,
                    plan: None,
                }),
            }
        };
        let mut r = rules();
        // Infeasible from t = 5 for 10 s (the default minimum): raised at
        // 15, dated 5; feasible again from 30: cleared at 40, dated 30.
        let mut out = run(&mut r, (0..5).map(|i| steer(f64::from(i), true)));
        assert!(out.is_empty());
        out.extend(run(&mut r, (5..30).map(|i| steer(f64::from(i), false))));
        out.extend(run(&mut r, (30..=45).map(|i| steer(f64::from(i), true))));
        let edges: Vec<(bool, f64)> = out.iter().map(|t| (t.raised, t.t)).collect();
        assert_eq!(edges, [(true, 5.0), (false, 30.0)], "{out:?}");
        assert_eq!(
            out[0].key,
            key(AlarmKind::SteeringInfeasible, Severity::Alarm, "")
        );
    }

    #[test]
    fn without_tolerances_there_is_no_deviation_alarm() {
        let mut r = AlarmRules::new(
            AlarmConfig::default(),
            None,
            StreamKind::ALL,
            AlarmState::default(),
        );
        assert!(run(&mut r, (0..100).map(|i| dta(f64::from(i), 500.0, 500.0))).is_empty());
    }

    fn attitude(t: f64, laser_age_s: Option<f64>) -> EngineOutput {
        EngineOutput {
            integrity: crate::fusion::Integrity::OK,
            t,
            values: EstimateValues::Attitude(AttitudeEstimate {
                pitch_deg: 0.0,
                roll_deg: 0.0,
                pitch_pred_deg: 0.0,
                roll_pred_deg: 0.0,
                pred_t: t,
                pitch_sigma_deg: None,
                roll_sigma_deg: None,
                pitch_pred_sigma_deg: None,
                laser_ok: laser_age_s.is_some_and(|a| a < 300.0),
                pitch_correction_deg: 0.0,
                laser_age_s,
                model_version: 0,
                incl_pitch_deg: 0.0,
                incl_roll_deg: 0.0,
            }),
        }
    }

    /// An `attitude` estimate with its pitch 1σ, the laser seen at t = 0.
    fn attitude_sigma(t: f64, sigma_deg: f64) -> EngineOutput {
        let mut o = attitude(t, Some(t.min(200.0)));
        if let EstimateValues::Attitude(a) = &mut o.values {
            a.pitch_sigma_deg = Some(sigma_deg);
        }
        o
    }

    #[test]
    fn an_uncertain_pitch_warns_alarms_and_clears_with_hysteresis() {
        let mut r = rules();
        // Before any laser sample the prior's σ raises nothing.
        let mut prior = attitude(-10.0, None);
        if let EstimateValues::Attitude(a) = &mut prior.values {
            a.pitch_sigma_deg = Some(0.5);
        }
        assert!(run(&mut r, [prior]).is_empty());
        // σ 0.02° for 100 s, then 0.07° (over the 0.05° warn) from t = 100,
        // then 0.12° (over the 0.1° alarm) from t = 200: each raised once it
        // has held 10 s, dated when it began.
        let mut out = run(&mut r, (0..100).map(|i| attitude_sigma(f64::from(i), 0.02)));
        out.extend(run(
            &mut r,
            (100..200).map(|i| attitude_sigma(f64::from(i), 0.07)),
        ));
        out.extend(run(
            &mut r,
            (200..300).map(|i| attitude_sigma(f64::from(i), 0.12)),
        ));
        let raised: Vec<_> = out
            .iter()
            .map(|t| (t.key.severity, t.raised, t.t))
            .collect();
        assert_eq!(
            raised,
            [
                (Severity::Warn, true, 100.0),
                (Severity::Alarm, true, 200.0)
            ]
        );
        assert!(
            out.iter()
                .all(|t| t.key.kind == AlarmKind::AttitudeUncertainty)
        );
        assert!(out[0].message.contains("0.070°"), "{}", out[0].message);
        // 0.095° is under the alarm limit but not 10 % under it: no clear.
        let out = run(
            &mut r,
            (300..400).map(|i| attitude_sigma(f64::from(i), 0.095)),
        );
        assert!(out.is_empty(), "{out:?}");
        // 0.03°: both clear after 10 s, dated when σ fell.
        let out = run(
            &mut r,
            (400..500).map(|i| attitude_sigma(f64::from(i), 0.03)),
        );
        assert_eq!(out.len(), 2);
        assert!(out.iter().all(|t| !t.raised && t.t == 400.0), "{out:?}");
    }

    #[test]
    fn a_time_limit_reads_in_seconds_below_two_minutes() {
        assert_eq!(span(30.0), "30 s");
        assert_eq!(span(119.0), "119 s");
        assert_eq!(span(300.0), "5 min");
    }

    #[test]
    fn a_laser_dropout_warns_after_five_minutes_alarms_after_thirty_and_clears() {
        let mut r = rules();
        // No laser yet: nothing. Then the last sample at t = 100.
        let mut out = run(&mut r, (0..100).map(|i| attitude(f64::from(i), None)));
        out.extend(run(
            &mut r,
            (100..2000).map(|i| attitude(f64::from(i), Some(f64::from(i) - 100.0))),
        ));
        let raised: Vec<_> = out.iter().map(|t| (t.key.severity, t.t)).collect();
        // Older than 300 s first at t = 401, than 1800 s at t = 1901.
        assert_eq!(raised, [(Severity::Warn, 401.0), (Severity::Alarm, 1901.0)]);
        let out = run(&mut r, [attitude(2000.0, Some(0.5))]);
        assert_eq!(out.len(), 2);
        assert!(out.iter().all(|t| !t.raised && t.t == 2000.0));
    }

    fn inclinometer(t: f64) -> Reading {
        Reading {
            t,
            data: SensorData::Inclinometer {
                pitch_deg: 0.0,
                roll_deg: 0.0,
                temp_c: None,
            },
        }
    }

    #[test]
    fn a_sensor_silent_for_five_of_its_periods_is_stale_until_it_reads_again() {
        let mut r = rules();
        let mut out = Vec::new();
        // 2 s readings to t = 40: stale after max(5 × 2, 10) = 10 s.
        for i in 0..=20 {
            r.reading(&inclinometer(2.0 * f64::from(i)), &mut out);
        }
        r.tick(49.0, &mut out);
        assert!(out.is_empty());
        r.tick(51.0, &mut out);
        r.tick(60.0, &mut out);
        assert_eq!(out.len(), 1, "{out:?}");
        assert!(out[0].raised && out[0].t == 50.0);
        assert_eq!(
            out[0].key,
            key(AlarmKind::StaleSensor, Severity::Alarm, "inclinometer")
        );
        assert!(
            out[0].message.contains("no inclinometer reading for 11 s"),
            "{}",
            out[0].message
        );
        r.reading(&inclinometer(61.0), &mut out);
        assert_eq!(out.len(), 2);
        assert!(!out[1].raised && out[1].t == 61.0);
        // Silent again; the readings of the silence forwarded late clear
        // it, dated no earlier than its raise.
        r.tick(80.0, &mut out);
        assert!(out[2].raised && out[2].t == 71.0, "{out:?}");
        r.reading(&inclinometer(63.0), &mut out);
        assert!(!out[3].raised && out[3].t == 71.0, "{out:?}");
        // The laser is not judged stale: its silence is a laser dropout.
        let mut laser_only = rules();
        let mut out = Vec::new();
        for i in 0..=20 {
            let laser = Reading {
                t: 30.0 * f64::from(i),
                data: SensorData::Laser {
                    pitch_deg: 0.0,
                    roll_deg: 0.0,
                    yaw_deg: None,
                    position: None,
                },
            };
            laser_only.reading(&laser, &mut out);
        }
        laser_only.tick(1e6, &mut out);
        assert!(out.is_empty(), "{out:?}");
        // A sensor with fewer than three intervals is not judged.
        let mut fresh = rules();
        let mut out = Vec::new();
        fresh.reading(&inclinometer(0.0), &mut out);
        fresh.tick(1e6, &mut out);
        assert!(out.is_empty());
    }

    fn zupt(t: f64, aligned: bool, sigma_m: f64) -> EngineOutput {
        let mut output = crate::fusion::estimate::zupt_for_tests(t, None);
        if let EstimateValues::Zupt(z) = &mut output.values {
            (z.zv, z.aligned) = (false, aligned);
            z.position_sigma_m = [sigma_m, sigma_m, 0.001];
        }
        output
    }

    #[test]
    fn the_ins_uncertainty_and_a_reset_are_raised_and_cleared() {
        let mut r = rules();
        // σ 60 mm per axis: 84.9 mm horizontally, under 100; 80 mm per
        // axis from t = 5: 113 mm, warn raised at t = 15, dated 5.
        let mut out = run(&mut r, (0..5).map(|i| zupt(f64::from(i), true, 0.060)));
        out.extend(run(
            &mut r,
            (5..=15).map(|i| zupt(f64::from(i), true, 0.080)),
        ));
        assert_eq!(out.len(), 1, "{out:?}");
        assert_eq!(
            (out[0].key.kind, out[0].t),
            (AlarmKind::InsUncertainty, 5.0)
        );
        // The engine loses its solution at t = 16: a reset at once; the
        // uncertainty is not judged while unaligned; aligned again at 30.
        let out = run(&mut r, (16..30).map(|i| zupt(f64::from(i), false, 0.0)));
        assert_eq!(out.len(), 1, "{out:?}");
        assert_eq!(
            (out[0].key.kind, out[0].raised, out[0].t),
            (AlarmKind::EngineReset, true, 16.0)
        );
        // The reset clears 10 s on; the uncertainty is held a minute from
        // its onset (t = 5), so it clears at t = 65, dated 30.
        let out = run(&mut r, (30..64).map(|i| zupt(f64::from(i), true, 0.001)));
        let cleared: Vec<_> = out.iter().map(|t| (t.key.kind, t.raised, t.t)).collect();
        assert_eq!(cleared, [(AlarmKind::EngineReset, false, 30.0)]);
        let out = run(&mut r, (64..70).map(|i| zupt(f64::from(i), true, 0.001)));
        let cleared: Vec<_> = out.iter().map(|t| (t.key.kind, t.raised, t.t)).collect();
        assert_eq!(cleared, [(AlarmKind::InsUncertainty, false, 30.0)]);
    }

    fn with_integrity(mut output: EngineOutput, integrity: Integrity) -> EngineOutput {
        output.integrity = integrity;
        output
    }

    /// The `integrity` transitions: (severity, raised, t).
    fn integrity_edges(out: &[Transition]) -> Vec<(Severity, bool, f64)> {
        out.iter()
            .filter(|t| t.key.kind == AlarmKind::Integrity)
            .map(|t| (t.key.severity, t.raised, t.t))
            .collect()
    }

    #[test]
    fn an_engine_lost_alarms_degraded_warns_and_its_first_alignment_does_neither() {
        let mut r = rules();
        let lost = Integrity::lost(IntegrityReason::Unaligned);
        // Aligning from the start for a minute: nothing.
        let out = run(
            &mut r,
            (0..60).map(|i| with_integrity(zupt(f64::from(i), false, 0.0), lost)),
        );
        assert!(
            out.iter().all(|t| t.key.kind != AlarmKind::Integrity),
            "{out:?}"
        );
        // Vouched for from t = 60; tilt disagrees at t = 100 for 20 s:
        // alarm at once, warn after 10 s, both dated 100.
        let ok = (60..100).map(|i| zupt(f64::from(i), true, 0.001));
        let tilt = Integrity::lost(IntegrityReason::TiltDisagrees);
        let bad = (100..120).map(|i| with_integrity(zupt(f64::from(i), true, 0.001), tilt));
        let out = run(&mut r, ok.chain(bad));
        let edges: Vec<_> = out
            .iter()
            .filter(|t| t.key.kind == AlarmKind::Integrity)
            .map(|t| (t.key.severity, t.key.subject.as_str(), t.raised, t.t))
            .collect();
        assert_eq!(
            edges,
            [
                (Severity::Alarm, "zupt", true, 100.0),
                (Severity::Warn, "zupt", true, 100.0)
            ]
        );
        assert!(
            out[0].message.contains("lost (tilt_disagrees)"),
            "{}",
            out[0].message
        );
        // Recovering (degraded) from t = 120 to 130, then ok: the alarm
        // clears once lost has been gone 10 s and a minute has passed
        // since its onset (t = 160), dated 120; the warn likewise, dated 130.
        let recovering = Integrity::degraded(IntegrityReason::Recovering);
        let out = run(
            &mut r,
            (120..130)
                .map(|i| with_integrity(zupt(f64::from(i), true, 0.001), recovering))
                .chain((130..200).map(|i| zupt(f64::from(i), true, 0.001))),
        );
        let edges = integrity_edges(&out);
        assert_eq!(
            edges,
            [
                (Severity::Warn, false, 130.0),
                (Severity::Alarm, false, 120.0)
            ]
        );
        // Unaligned again after having been ok is a fault; degraded for
        // 9 s is not yet one.
        let out = run(
            &mut r,
            (200..209)
                .map(|i| with_integrity(zupt(f64::from(i), true, 0.001), recovering))
                .chain((209..215).map(|i| with_integrity(zupt(f64::from(i), false, 0.0), lost))),
        );
        let edges = integrity_edges(&out);
        assert_eq!(
            edges,
            [
                (Severity::Alarm, true, 209.0),
                (Severity::Warn, true, 200.0)
            ]
        );
    }

    #[test]
    fn a_stage_inherits_integrity_and_raises_no_alarm_of_its_own() {
        let mut r = rules();
        let lost = Integrity::lost(IntegrityReason::Source);
        let out = run(
            &mut r,
            (0..60).map(|i| with_integrity(dta(f64::from(i), 0.0, 0.0), lost)),
        );
        assert!(out.is_empty(), "{out:?}");
    }

    #[test]
    fn a_lost_deviation_is_not_judged_and_its_alarm_stays_as_it_was() {
        let mut r = rules();
        // 55 mm raises the warn; the source is then lost at 0 mm for two
        // minutes: no clear. Lost at 80 mm from a fresh start: no raise.
        let out = run(&mut r, (0..=10).map(|i| dta(f64::from(i), 55.0, 0.0)));
        assert_eq!(out.len(), 1);
        let lost = Integrity::lost(IntegrityReason::Source);
        let out = run(
            &mut r,
            (11..130).map(|i| with_integrity(dta(f64::from(i), 0.0, 0.0), lost)),
        );
        assert!(out.is_empty(), "{out:?}");
        let mut fresh = rules();
        let out = run(
            &mut fresh,
            (0..60).map(|i| with_integrity(dta(f64::from(i), 80.0, 0.0), lost)),
        );
        assert!(out.is_empty(), "{out:?}");
    }

    #[test]
    fn a_noisy_deviation_hovering_at_its_limit_raises_once() {
        let mut r = rules();
        // An INS position: front horizontal 50 ± 8 mm (1σ 10 mm) for ten
        // minutes, against a 50 mm warn limit; each value held 12 s, so
        // past the 10 s minimum. With 10 % hysteresis alone it would flap
        // (42 mm is below 45); with the 2σ band (back below 30 mm) it is
        // raised once and stays raised.
        let noisy = |t: f64, h_mm: f64| {
            let mut o = dta(t, h_mm, 0.0);
            if let EstimateValues::Dta(d) = &mut o.values {
                d.front.sigma_horizontal_mm = Some(10.0);
            }
            o
        };
        let values = [58.0, 42.0];
        let out = run(
            &mut r,
            (0..600).map(|i| noisy(f64::from(i), values[(i / 12) as usize % 2])),
        );
        let raised = out.iter().filter(|t| t.raised).count();
        let cleared = out.iter().filter(|t| !t.raised).count();
        assert_eq!((raised, cleared), (1, 0), "{out:?}");
        // Back at 25 mm: cleared.
        let out = run(&mut r, (600..620).map(|i| noisy(f64::from(i), 25.0)));
        assert_eq!(out.len(), 1, "{out:?}");
        assert!(!out[0].raised && out[0].t == 600.0);
    }

    #[test]
    fn the_servers_downtime_is_not_a_sensors_silence() {
        let mut r = rules();
        let mut out = Vec::new();
        for i in 0..=20 {
            r.reading(&inclinometer(2.0 * f64::from(i)), &mut out);
        }
        // The server was down from t = 41 to t = 1000: at its first tick
        // the inclinometer has not yet had 10 s to speak again.
        r.resumed(1000.0);
        r.tick(1000.5, &mut out);
        r.tick(1009.0, &mut out);
        assert!(out.is_empty(), "{out:?}");
        // It stays silent: stale from 10 s after the resumption.
        r.tick(1011.0, &mut out);
        assert_eq!(out.len(), 1, "{out:?}");
        assert!(out[0].raised && out[0].t == 1010.0);
    }

    #[test]
    fn the_state_survives_a_snapshot() {
        let mut r = rules();
        run(&mut r, (0..=20).map(|i| dta(f64::from(i), 55.0, 0.0)));
        let json = serde_json::to_value(r.state()).unwrap();
        let state: AlarmState = serde_json::from_value(json).unwrap();
        let mut restored =
            AlarmRules::new(AlarmConfig::default(), r.tolerances, StreamKind::ALL, state);
        // All but what the active alarms read now, judged again at the
        // next estimate.
        assert_eq!(restored.state(), r.state());
        assert!(restored.now().is_empty() && !r.now().is_empty());
        // Still active: no second raise.
        assert!(
            run(
                &mut restored,
                (21..40).map(|i| dta(f64::from(i), 55.0, 0.0))
            )
            .is_empty()
        );
    }

    #[test]
    fn bad_settings_are_named() {
        let bad = AlarmConfig {
            laser_dropout_alarm_s: 10.0,
            ..AlarmConfig::default()
        };
        assert!(bad.validate().unwrap_err().contains("at or above"));
        let bad = AlarmConfig {
            min_duration_s: -1.0,
            ..AlarmConfig::default()
        };
        assert!(bad.validate().unwrap_err().contains("min_duration_s"));
        assert!(AlarmConfig::default().validate().is_ok());
    }
}
