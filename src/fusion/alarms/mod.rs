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
use super::declaration::Tolerances;
use super::descriptor::{DeviationSignal, Navigation, SignalKind, Signals};
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
            let limit = |l: super::declaration::Limits| if i == 0 { l.warn } else { l.alarm };
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
mod tests;
