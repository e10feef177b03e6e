//! The `zupt` engine: a FOG strapdown INS corrected by zero-velocity
//! updates whenever a three-condition detector finds the machine standing
//! still, and by level-instrument heights (Zhang et al. 2024).
//!
//! Per IMU reading:
//! 1. the reading enters the zero-velocity pipeline ([`zero_velocity`]):
//!    MV, ARE, SHOE and MAG over a window centred on it ([`detectors`]),
//!    the selected test, a binary median filter, a minimum run. Decisions
//!    come out late by a bounded amount ([`ZuptEngine::latency_bound_s`]:
//!    about 4 s at the defaults), and so do the estimates: each reading's
//!    estimate is made once its decision is known;
//! 2. the first reading decided still aligns the platform (levelling from
//!    its window's mean specific force, heading from `initial_yaw_deg`);
//! 3. each later reading advances the strapdown solution ([`strapdown`]);
//!    every `filter_period_s` the error-state covariance is propagated and
//!    the zero-velocity, height and (if enabled) odometer updates are made,
//!    with the estimated errors fed back ([`eskf`]).
//!
//! `level` and `odometer` readings wait until the (late) navigation time
//! reaches them. An IMU gap longer than `max_imu_gap_s` ends a stream: the
//! waiting readings are decided with the data there is, the navigation
//! state is held across the gap and its covariance grown, and the
//! detector's windows start afresh. IMU readings at or before the newest
//! one are dropped and counted.

pub mod detectors;
pub mod eskf;
pub mod estimate;
pub mod imu_screen;
pub mod odometer_scale;
pub mod params;
pub mod rest_check;
pub mod smoother;
pub mod strapdown;
pub mod zaru_noise;
pub mod zero_velocity;

use std::collections::VecDeque;

use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};

use self::detectors::Statistics;
use self::eskf::{
    ATT, Dynamics, ErrorStateFilter, ODOMETER, OdometerModel, POS, VEL, height_matrix,
    odometer_matrix, scale_matrix, zaru_matrix, zupt_matrix,
};
use self::estimate::{TrackPoint, ZuptEstimate};
use self::imu_screen::{ImuScreen, Screened};
use self::odometer_scale::{InsPush, MeasuredPush};
pub use self::params::{PARAMS, ZuptConfig, ZuptParams};
use self::rest_check::{Refusal, RestCheck, RestCheckConfig, Velocity};
use self::smoother::{Point, PushRecord};
use self::strapdown::{Increment, NavState};
use self::zaru_noise::ZaruNoise;
use self::zero_velocity::{Decision, DetectorKind, ZeroVelocityPipeline};
use super::angles::{deg, rad};
use super::descriptor::{EngineDescriptor, NoModel};
use super::estimate::{EngineOutput, EstimateValues};
use super::integrity::{Integrity, IntegrityReason};
use super::params::{ParamError, Params, Retired};
use super::reading::{Reading, SensorData, SensorKind};
use super::{Engine, EngineKind, SnapshotError};
use crate::fusion::geometry::{
    V3, attitude_from_euler, earth_rate_n, level, normal_gravity_mps2, radii_m,
};

/// Version of the engine's snapshot. A snapshot of another version is
/// refused as [`SnapshotError::Outdated`]; the machine is then rebuilt from
/// its stored readings. 2: integrated detector signals, learned rest
/// levels, zero-angular-rate updates; 3: the rest check; 4: the rest
/// check judges runs of rest, not readings; 5: the odometer's speed is
/// compared with the INS's mean over the same interval; the odometer
/// confirms rests, refuses a run at once, and aligns; 6: the noise of the
/// zero-angular-rate update is estimated from the rates; 7: the distance
/// the odometer carried (its scale error in the position σ); 8: the creep
/// a rest no odometer confirmed may hide (in the position σ); 9: the
/// odometer's scale and axis as filter states (issue 58); 10: a speed the
/// machine cannot have, pushes the odometer contradicts (issue 58).
pub const STATE_VERSION: u32 = 10;
/// Level or odometer readings kept waiting for the navigation time.
const MAX_PENDING_AIDS: usize = 1024;
/// Two odometer readings further apart than this bound no interval for
/// the slip check (the count since the origin is fused still).
const ODOMETER_MAX_GAP_S: f64 = 10.0;
/// Odometer readings refused this long in a row take back the run's slips
/// and open the INS position's and velocity's covariance along the axis
/// (a wheel slips for seconds; an INS that drifted stays refused); an
/// estimate this close to a refusal is `degraded`, s.
const ODOMETER_LOCKOUT_S: f64 = 10.0;
/// A speed beyond `max_speed_mps` by more than this many σ of the
/// filter's velocity along it is one the machine cannot have.
const SPEED_BOUND_SIGMAS: f64 = 3.0;
/// The odometer's distance and the engine's disagreeing by more than this
/// many σ make an estimate `degraded`.
const ODOMETER_DISAGREE_SIGMAS: f64 = 3.0;
/// The least σ of that disagreement: the odometer's resolution and the
/// reading's age against the engine's distance, m.
const ODOMETER_DISAGREE_FLOOR_M: f64 = 0.01;
/// The spacing of the INS distance kept to compare with the odometer, s.
const INS_DISTANCE_STEP_S: f64 = 0.05;

/// One IMU reading in working units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImuSample {
    pub t: f64,
    pub accel_mps2: V3,
    pub gyro_rad_per_s: V3,
}

impl ImuSample {
    /// An IMU reading's values (m/s², °/s) in working units.
    fn new(t: f64, accel_mps2: &[f64; 3], gyro_dps: &[f64; 3]) -> ImuSample {
        ImuSample {
            t,
            accel_mps2: V3::from(*accel_mps2),
            gyro_rad_per_s: V3::from(*gyro_dps).map(rad),
        }
    }
}

/// Counts of what the engine did with its readings.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ZuptStats {
    pub imu_used: u64,
    /// IMU readings at or before the newest one.
    pub imu_dropped: u64,
    /// Gaps longer than `max_imu_gap_s`.
    pub imu_gaps: u64,
    pub zupt_updates: u64,
    /// Zero-angular-rate updates.
    #[serde(default)]
    pub zaru_updates: u64,
    /// Pushes smoothed, and pushes too long to smooth.
    #[serde(default)]
    pub pushes_smoothed: u64,
    #[serde(default)]
    pub pushes_too_long: u64,
    pub height_updates: u64,
    /// Heights refused by the gate.
    pub heights_refused: u64,
    pub odometer_updates: u64,
    /// Odometer readings refused (a slipping wheel, a reset counter).
    pub odometer_refused: u64,
    /// Pushes that measured the odometer's scale, and those the gate
    /// refused ([`odometer_scale`]).
    #[serde(default)]
    pub odometer_scale_pushes: u64,
    #[serde(default)]
    pub odometer_scale_refused: u64,
    /// Readings the detector called still whose rest the check refused:
    /// for the filter's velocity, and for the odometer's advance.
    #[serde(default)]
    pub rests_refused_velocity: u64,
    #[serde(default)]
    pub rests_refused_odometer: u64,
    /// IMU readings refused as spikes, and taken for a frozen sensor's
    /// (issue 54, [`imu_screen`]).
    #[serde(default)]
    pub imu_spikes: u64,
    #[serde(default)]
    pub imu_frozen: u64,
    /// Updates skipped because the innovation covariance was singular.
    pub updates_failed: u64,
    /// Level or odometer readings dropped because too many were waiting.
    pub aids_dropped: u64,
    /// Times the solution became non-finite and alignment started again.
    pub navigation_resets: u64,
}

/// The navigation once aligned.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Navigation {
    state: NavState,
    filter: ErrorStateFilter,
    /// b̂_a, m/s², and b̂_g, rad/s: subtracted from every reading.
    accel_bias_mps2: V3,
    gyro_bias_rad_per_s: V3,
    /// Along-track metres the strapdown integrated since alignment (no
    /// filter corrections), and (t, metres) over the last
    /// [`ODOMETER_MAX_GAP_S`] at least every [`INS_DISTANCE_STEP_S`]: the
    /// INS's advance over any odometer interval (the slip check) and the
    /// engine's distance at a reading's time, interpolated.
    ins_distance_m: f64,
    ins_distance_history: VecDeque<(f64, f64)>,
    /// The previous IMU reading (the input is averaged over each interval);
    /// `None` right after alignment or a gap.
    previous: Option<ImuSample>,
    /// Time, ∫fⁿ dt and ∫(ω̃ − b̂_g) dt since the last filter epoch, and
    /// whether every reading in it was decided zero velocity.
    interval_s: f64,
    force_integral: V3,
    rate_integral: V3,
    interval_still: bool,
    /// The noise of a still interval's mean rate, from the rates
    /// ([`zaru_noise`]).
    zaru_noise: ZaruNoise,
    /// Along-track distance: displacement projected on the body's x axis.
    distance_m: f64,
    /// The push in progress, from the last still epoch (smoothing on);
    /// `None` after one too long to smooth, until the next still epoch.
    push: Option<PushRecord>,
    /// Height of the start point, set by the first level reading.
    height_datum_m: Option<f64>,
    /// The newest height not yet used, and odometer reading not yet used.
    pending_height_m: Option<f64>,
    pending_odometer: Option<OdometerFix>,
    /// The odometer's scale error and axis as estimated (their
    /// covariance is the filter's [`ODOMETER`] block).
    odometer: OdometerModel,
    /// How far the position could be off along the machine's axis (NED m,
    /// along the axis at each step) by what no evidence checked, a bound
    /// the reported position σ grows by ([`with_creep_bound`]): the creep
    /// a rest no odometer confirmed may hide, `max_speed_mps` times each
    /// such still epoch and each IMU gap (an IMU cannot tell a steady
    /// creep from a stop: no acceleration, so a rest the detector calls
    /// wrongly loses that distance unseen). The down part is dropped at
    /// each height the level gives.
    unverified_m: V3,
    /// Where the odometer's count is compared from (the first odometer
    /// reading after alignment; moved on by every slip), and by how much
    /// its count since then, scale-corrected, and the engine's along-track
    /// advance disagree at the newest odometer reading, m: which of the
    /// two is wrong is not known, so the reported σ along the axis grows
    /// by it, and beyond [`ODOMETER_DISAGREE_SIGMAS`] the estimate is
    /// `degraded` (`odometer_disagrees`).
    odometer_origin: Option<OdometerOrigin>,
    odometer_disagreement_m: f64,
    /// The first refusal of the current run of odometer readings refused
    /// (a slip, or a count the gate refused), the newest refusal's time,
    /// and what the run's slips moved the origin by, m (the monitor of
    /// the odometer against the INS, [`ODOMETER_LOCKOUT_S`]).
    odometer_refused_from_t: Option<f64>,
    odometer_refused_t: Option<f64>,
    odometer_slipped_m: f64,
    /// The newest odometer count, every slip booked so far
    /// ([`OdometerInterval::possible_slip_m`]), m, and the
    /// INS's own motion since the newest rest the odometer confirmed
    /// before the push ([`odometer_scale`]).
    newest_count_m: Option<f64>,
    slipped_total_m: f64,
    ins_push: Option<InsPush>,
    /// Whether the newest epoch's speed was beyond the machine's
    /// `max_speed_mps` by more than [`SPEED_BOUND_SIGMAS`] σ: the INS has
    /// run away (`lost`, `speed_implausible`).
    speed_implausible: bool,
}

/// An odometer reading not yet fused.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct OdometerFix {
    /// Its time and count, m.
    t: f64,
    counted_m: f64,
    /// The interval since the reading before (since the one before that
    /// was fused, when readings came faster than the epochs); `None`
    /// across a gap.
    interval: Option<OdometerInterval>,
}

/// The interval between two odometer readings: the count's and the
/// INS's advance over it, m, and its length, s.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct OdometerInterval {
    advance_m: f64,
    ins_advance_m: f64,
    dt_s: f64,
}

impl OdometerInterval {
    /// What the count advanced beyond `scale` times the INS's advance, m.
    fn excess_m(&self, scale: f64) -> f64 {
        self.advance_m - scale * self.ins_advance_m
    }

    /// The part of [`Self::excess_m`] a wheel can have slipped: the machine's true
    /// advance lies between 0 and `max_speed_mps` over the interval, so
    /// the count is off by at most its own advance (all counted at a
    /// standstill) and at least its advance less the fastest possible one.
    /// The rest of the excess is the INS's error (a backward drift while
    /// the count stood still is no slip), m.
    fn possible_slip_m(&self, scale: f64, max_speed_mps: f64) -> f64 {
        let fastest_m = (scale * max_speed_mps * self.dt_s).max(0.0);
        self.excess_m(scale)
            .clamp(self.advance_m - fastest_m, self.advance_m)
    }
}

/// Where the odometer's count is compared from: its count and the
/// engine's along-track distance there, m, and that distance's 1σ then
/// (added to the noise of every comparison).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct OdometerOrigin {
    counted_m: f64,
    engine_m: f64,
    sigma_m: f64,
}

/// The `zupt` engine; see the module documentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZuptEngine {
    /// [`STATE_VERSION`] when the snapshot was taken.
    state_version: u32,
    params: Params,
    #[serde(skip_serializing, default = "placeholder_config")]
    config: ZuptConfig,
    pipeline: ZeroVelocityPipeline<ImuSample>,
    newest_imu_t: Option<f64>,
    navigation: Option<Navigation>,
    /// Level readings (t, height m) and odometer readings (t, distance m)
    /// waiting for the navigation time.
    levels: VecDeque<(f64, f64)>,
    odometers: VecDeque<(f64, f64)>,
    /// The newest odometer reading the navigation time has passed.
    odometer: Option<(f64, f64)>,
    /// The check of called rests (`rest_check`).
    rest_check: RestCheck,
    /// The screen of IMU readings for spikes and a frozen sensor.
    imu_screen: ImuScreen,
    /// The newest navigated reading's decision (the detector's figures a
    /// held estimate repeats).
    last_decision: Option<Decision>,
    /// When the frozen IMU was said to be frozen (one held estimate, `lost`).
    imu_frozen_said: Option<f64>,
    stats: ZuptStats,
    /// Scratch for the pipeline's decisions, kept to spare an allocation
    /// per reading; always empty between calls.
    #[serde(skip)]
    decided: Vec<(ImuSample, Decision)>,
}

/// Used only while deserialising; `restore` rebuilds the config from `params`.
fn placeholder_config() -> ZuptConfig {
    ZuptConfig::from_params(&Params::defaults(PARAMS)).expect("default parameters are valid")
}

impl ZuptEngine {
    /// A fresh engine.
    pub fn new(params: Params) -> Result<ZuptEngine, ParamError> {
        let config = ZuptConfig::from_params(&params)?;
        Ok(ZuptEngine {
            state_version: STATE_VERSION,
            params,
            config,
            pipeline: ZeroVelocityPipeline::new(config.pipeline),
            newest_imu_t: None,
            navigation: None,
            levels: VecDeque::new(),
            odometers: VecDeque::new(),
            odometer: None,
            rest_check: RestCheck::default(),
            imu_screen: ImuScreen::default(),
            last_decision: None,
            imu_frozen_said: None,
            stats: ZuptStats::default(),
            decided: Vec::new(),
        })
    }

    /// An engine with every parameter at its default.
    pub fn with_defaults() -> ZuptEngine {
        ZuptEngine::new(Params::defaults(PARAMS)).expect("default parameters are valid")
    }

    /// Continues from a snapshot taken by [`Engine::snapshot`].
    /// A snapshot of another [`STATE_VERSION`] is refused as outdated.
    pub fn restore(snapshot: serde_json::Value) -> Result<ZuptEngine, SnapshotError> {
        SnapshotError::check_version(EngineKind::Zupt, &snapshot, STATE_VERSION)?;
        let mut engine: ZuptEngine = SnapshotError::parse(EngineKind::Zupt, snapshot)?;
        let params = engine.params.revalidated(PARAMS)?;
        engine.config = ZuptConfig::from_params(&params)?;
        engine.params = params;
        if engine.pipeline.config() != &engine.config.pipeline {
            return Err(SnapshotError::Invalid(
                "detector state does not match the parameters".into(),
            ));
        }
        if let Some(nav) = &engine.navigation
            && !nav.filter.is_sane()
        {
            return Err(SnapshotError::Invalid("covariance is not valid".into()));
        }
        engine.levels.truncate(MAX_PENDING_AIDS);
        engine.odometers.truncate(MAX_PENDING_AIDS);
        Ok(engine)
    }

    /// The working configuration.
    pub fn config(&self) -> &ZuptConfig {
        &self.config
    }

    /// What the engine has done with its readings.
    pub fn stats(&self) -> ZuptStats {
        self.stats
    }

    /// The longest an IMU reading waits for its estimate, in seconds of
    /// its own stream, at a sample period of `period_s`.
    pub fn latency_bound_s(&self, period_s: f64) -> f64 {
        self.config.pipeline.lookahead_samples() as f64 * period_s
            + self.config.pipeline.min_run_s
            + period_s
    }

    /// The error-state covariance, once aligned (tests check consistency).
    pub fn covariance(&self) -> Option<&eskf::Covariance> {
        self.navigation.as_ref().map(|n| &n.filter.p)
    }

    /// The Earth's rotation in the body frame, for ARE and SHOE.
    fn earth_rate_b(&self, accel_mps2: &V3) -> V3 {
        let attitude = match &self.navigation {
            Some(nav) => nav.state.attitude,
            None => {
                let (roll, pitch) = level(accel_mps2);
                attitude_from_euler(roll, pitch, self.config.initial_yaw_rad)
            }
        };
        let (lat, _) = match &self.navigation {
            Some(nav) => self.config.site.at(&nav.state.position_m),
            None => (self.config.site.lat_rad, 0.0),
        };
        attitude.inverse() * earth_rate_n(lat)
    }

    /// Whether an IMU reading at `t` is at or before the newest taken
    /// (counted as dropped).
    fn is_late(&mut self, t: f64) -> bool {
        let late = self.newest_imu_t.is_some_and(|newest| t <= newest);
        self.stats.imu_dropped += u64::from(late);
        late
    }

    /// Takes the time `t` of an IMU reading that is not late: a gap longer
    /// than `max_imu_gap_s` ends the stream first.
    fn admit_imu(&mut self, t: f64, out: &mut Vec<EngineOutput>) {
        if let Some(newest) = self.newest_imu_t
            && t - newest > self.config.max_imu_gap_s
        {
            self.stats.imu_gaps += 1;
            self.end_stream(out);
            if let Some(nav) = &mut self.navigation {
                let gap_s = t - newest;
                nav.filter.inflate(gap_s);
                // The machine may have moved in the gap, at up to its
                // fastest; nothing measured it.
                nav.unverified_m +=
                    nav.state.attitude * V3::x() * (self.config.max_speed_mps * gap_s);
                nav.previous = None;
                nav.ins_push = None;
                // No INS distance across the gap: no odometer interval
                // reaching back over it is compared.
                nav.ins_distance_history.clear();
                // Rates across the gap are not compared.
                nav.zaru_noise.interrupted();
                // A push across a gap is not smoothed.
                nav.push = None;
            }
        }
        self.newest_imu_t = Some(t);
        self.stats.imu_used += 1;
    }

    fn on_imu(&mut self, sample: ImuSample, out: &mut Vec<EngineOutput>) {
        if self.is_late(sample.t) {
            return;
        }
        match self.imu_screen.screen(&sample) {
            Screened::Take => {}
            Screened::Spike => {
                self.stats.imu_spikes += 1;
                return;
            }
            Screened::Frozen => {
                self.stats.imu_frozen += 1;
                // The first frozen reading ends the stream and says so;
                // the next are not taken (no estimate) until the IMU is
                // live again, and the time between is a gap.
                if self.imu_frozen_said.is_none() {
                    self.end_stream(out);
                    out.push(self.held_estimate(sample.t));
                    self.imu_frozen_said = Some(sample.t);
                }
                return;
            }
        }
        self.imu_frozen_said = None;
        self.admit_imu(sample.t, out);
        let earth_rate_b = self.earth_rate_b(&sample.accel_mps2);
        let mut decided = std::mem::take(&mut self.decided);
        self.pipeline.push(
            sample.t,
            sample.accel_mps2,
            sample.gyro_rad_per_s,
            sample,
            &earth_rate_b,
            &mut decided,
        );
        self.navigate_all(&mut decided, out);
        self.decided = decided;
    }

    /// Feeds a reading with its zero-velocity decision given from outside
    /// (the evaluation's oracle, which knows the truth): an IMU reading
    /// skips the detector and is navigated at once; other readings are
    /// fed as usual.
    pub fn feed_decided(
        &mut self,
        reading: &Reading,
        zero_velocity: bool,
        out: &mut Vec<EngineOutput>,
    ) {
        let SensorData::Imu {
            accel_mps2,
            gyro_dps,
        } = &reading.data
        else {
            return self.feed(reading, out);
        };
        if self.is_late(reading.t) {
            return;
        }
        self.admit_imu(reading.t, out);
        let sample = ImuSample::new(reading.t, accel_mps2, gyro_dps);
        let decision = Decision {
            zv: zero_velocity,
            still: zero_velocity,
            statistics: Statistics::default(),
            thresholds: self.config.pipeline.thresholds,
        };
        out.push(self.navigate(sample, decision));
    }

    /// Navigates decided readings in order, leaving `decided` empty.
    fn navigate_all(
        &mut self,
        decided: &mut Vec<(ImuSample, Decision)>,
        out: &mut Vec<EngineOutput>,
    ) {
        for (sample, decision) in decided.drain(..) {
            out.push(self.navigate(sample, decision));
        }
    }

    /// Decides and navigates every waiting IMU reading.
    fn end_stream(&mut self, out: &mut Vec<EngineOutput>) {
        // The flush tests the last windows: the Earth rate comes from the
        // navigation's attitude, or (not aligned yet) a level body.
        let level_body = V3::new(0.0, 0.0, -1.0);
        let earth_rate_b = self.earth_rate_b(&level_body);
        let mut decided = std::mem::take(&mut self.decided);
        self.pipeline.flush(&earth_rate_b, &mut decided);
        self.navigate_all(&mut decided, out);
        self.decided = decided;
    }

    fn queue_aid(queue: &mut VecDeque<(f64, f64)>, stats: &mut ZuptStats, t: f64, value: f64) {
        if queue.len() == MAX_PENDING_AIDS {
            queue.pop_front();
            stats.aids_dropped += 1;
        }
        // Kept in time order; a late one is slotted in.
        let at = queue.partition_point(|&(queued_t, _)| queued_t <= t);
        queue.insert(at, (t, value));
    }

    /// Takes the level and odometer readings the navigation time `t` has
    /// reached.
    fn take_aids(&mut self, t: f64) {
        while let Some(&(level_t, height_m)) = self.levels.front() {
            if level_t > t {
                break;
            }
            self.levels.pop_front();
            if let Some(nav) = &mut self.navigation {
                nav.pending_height_m = Some(height_m);
            }
        }
        while let Some(&(odo_t, distance_m)) = self.odometers.front() {
            if odo_t > t {
                break;
            }
            self.odometers.pop_front();
            // One at or before the newest taken (slotted in too late) is
            // dropped: the intervals stay in order.
            if self.odometer.is_some_and(|(prev_t, _)| odo_t <= prev_t) {
                self.stats.aids_dropped += 1;
                continue;
            }
            if let Some(nav) = &mut self.navigation {
                nav.odometer_read(
                    self.odometer,
                    odo_t,
                    distance_m,
                    self.config.odometer_window.odometer_advance_m,
                );
            }
            // Kept whether or not the rest check is on: the odometer's
            // window confirms rests for the creep bound and the scale.
            self.rest_check
                .odometer(&self.config.odometer_window, odo_t, distance_m);
            self.odometer = Some((odo_t, distance_m));
        }
    }

    fn navigate(&mut self, sample: ImuSample, mut decision: Decision) -> EngineOutput {
        let config = self.config;
        // Not aligned yet: only the odometer can veto the rest that aligns.
        if self.navigation.is_none()
            && let Some(check) = &config.rest_check
        {
            check_rest(
                check,
                &mut self.rest_check,
                &mut self.stats,
                sample.t,
                None,
                &mut decision,
            );
        }
        // A rest the detector misses (it shakes) aligns the platform too
        // once the odometer stood for a whole window.
        let odometer_still = || {
            config
                .rest_check
                .as_ref()
                .is_some_and(|check| self.rest_check.odometer_still(check, sample.t))
        };
        if self.navigation.is_none()
            && (decision.zv || config.pipeline.detector == DetectorKind::None || odometer_still())
        {
            self.navigation = Some(self.align(&decision.statistics, sample));
        }
        let Some(nav) = self.navigation.as_mut() else {
            self.take_aids(sample.t);
            return self.unaligned_estimate(sample.t, &decision);
        };
        let mut raw_step = None;
        if let Some(previous) = nav.previous {
            let dt_s = sample.t - previous.t;
            let increment = Increment {
                accel_mps2: (previous.accel_mps2 + sample.accel_mps2) * 0.5 - nav.accel_bias_mps2,
                gyro_rad_per_s: (previous.gyro_rad_per_s + sample.gyro_rad_per_s) * 0.5
                    - nav.gyro_bias_rad_per_s,
                dt_s,
            };
            let before = nav.state.position_m;
            let force_n = nav.state.advance(&config.site, &increment);
            raw_step = Some((
                (previous.accel_mps2 + sample.accel_mps2) * 0.5,
                (previous.gyro_rad_per_s + sample.gyro_rad_per_s) * 0.5,
                dt_s,
            ));
            let advance_m = along_track(&nav.state, &(nav.state.position_m - before));
            nav.distance_m += advance_m;
            nav.ins_distance_m += advance_m;
            nav.interval_s += dt_s;
            nav.force_integral += force_n * dt_s;
            nav.rate_integral += increment.gyro_rad_per_s * dt_s;
        }
        nav.record_ins_distance(sample.t);
        // The aids after the step, so an odometer reading up to `sample.t`
        // finds the INS distance at its time.
        self.take_aids(sample.t);
        let Some(nav) = self.navigation.as_mut() else {
            return self.unaligned_estimate(sample.t, &decision);
        };
        if let Some(check) = &config.rest_check {
            let p_v = nav.filter.p.fixed_view::<3, 3>(VEL, VEL).into_owned();
            let forward = nav.state.attitude * V3::x();
            let velocity = Velocity {
                velocity_mps: &nav.state.velocity_mps,
                p_v: &p_v,
                forward: &forward,
            };
            check_rest(
                check,
                &mut self.rest_check,
                &mut self.stats,
                sample.t,
                Some(velocity),
                &mut decision,
            );
        }
        if nav.previous.is_some() {
            nav.interval_still &= decision.zv;
        }
        if let (Some((accel, gyro, dt_s)), Some(push)) = (raw_step, &mut nav.ins_push) {
            push.advance(&config.site, &accel, &gyro, dt_s, decision.zv);
        }
        nav.previous = Some(sample);
        let mut smoothed_push = None;
        if nav.interval_s >= config.filter_period_s {
            let rest_confirmed = self
                .rest_check
                .odometer_still(&config.odometer_window, sample.t);
            smoothed_push = nav.epoch(
                &config,
                sample.t,
                decision.zv,
                rest_confirmed,
                &mut self.stats,
            );
            // Readings within range but absurd for long enough (a broken
            // sensor) can run the solution off to infinity: start again at
            // the next still window rather than report garbage.
            if !nav.is_finite() {
                self.navigation = None;
                self.stats.navigation_resets += 1;
                self.rest_check.forget_motion();
            }
        }
        self.last_decision = Some(decision);
        let Some(nav) = self.navigation.as_ref() else {
            return self.unaligned_estimate(sample.t, &decision);
        };
        self.navigated_estimate(nav, sample.t, &decision, smoothed_push, None)
    }

    /// The estimate while the IMU is frozen at `t`: the navigation held
    /// since the last live reading, its σ grown over the frozen time as
    /// over a gap, `lost` (`sensor_frozen`).
    fn held_estimate(&self, t: f64) -> EngineOutput {
        let decision = Decision {
            zv: false,
            still: false,
            ..self.last_decision.unwrap_or(Decision {
                zv: false,
                still: false,
                statistics: Statistics::default(),
                thresholds: self.config.pipeline.thresholds,
            })
        };
        let held_s = (t - self.imu_screen.frozen_since_t().unwrap_or(t)).max(0.0);
        let mut output = match &self.navigation {
            Some(nav) => self.navigated_estimate(nav, t, &decision, None, Some(held_s)),
            None => self.unaligned_estimate(t, &decision),
        };
        output.integrity = Integrity::lost(IntegrityReason::SensorFrozen);
        output
    }

    /// The estimate of the navigation `nav` at `t`; `held_s`: held that
    /// long without inertial data (its σ grown as over a gap).
    fn navigated_estimate(
        &self,
        nav: &Navigation,
        t: f64,
        decision: &Decision,
        smoothed_push: Option<Vec<TrackPoint>>,
        held_s: Option<f64>,
    ) -> EngineOutput {
        let config = &self.config;
        let (roll, pitch, yaw) = nav.state.euler();
        let position = nav.state.position_m;
        let forward = nav.state.attitude * V3::x();
        let mut unverified_m = nav.unverified_m + forward * nav.odometer_disagreement_m.abs();
        let inflated;
        let filter = match held_s {
            Some(held_s) => {
                let mut filter = nav.filter.clone();
                filter.inflate(held_s);
                unverified_m += forward * (config.max_speed_mps * held_s);
                inflated = filter;
                &inflated
            }
            None => &nav.filter,
        };
        let sigma = with_creep_bound(&filter.sigma(POS), &unverified_m);
        let attitude_sigma = filter.sigma(ATT);
        let yaw_sigma_deg = deg(attitude_sigma.z);
        let tilt_sigma_deg = tilt_sigma(&filter.p, yaw).map(deg);
        let velocity = nav.state.velocity_mps;
        EngineOutput {
            t,
            values: EstimateValues::Zupt(
                self.estimate(
                    decision,
                    true,
                    [position.x, position.y, position.z],
                    nav.distance_m,
                    [velocity.x, velocity.y, velocity.z],
                    (roll, pitch, yaw),
                    [sigma.x, sigma.y, sigma.z],
                    nav.height_datum_m.map(|datum| datum - position.z),
                    Some(yaw_sigma_deg),
                    Some([
                        deg(attitude_sigma.x),
                        deg(attitude_sigma.y),
                        deg(attitude_sigma.z),
                    ]),
                    Some(tilt_sigma_deg),
                    smoothed_push,
                    // Estimated only while fused.
                    nav.odometer_origin
                        .filter(|_| config.odometer_aiding)
                        .map(|_| {
                            let sigma = filter.p[(ODOMETER, ODOMETER)].max(0.0).sqrt();
                            (1.0 + nav.odometer.scale_error, sigma)
                        }),
                ),
            ),
            integrity: nav.integrity(t),
        }
    }

    /// Before alignment: at the start point, levelled from the window.
    fn unaligned_estimate(&self, t: f64, decision: &Decision) -> EngineOutput {
        let (roll, pitch) = level(&decision.statistics.mean_accel_mps2);
        EngineOutput {
            t,
            values: EstimateValues::Zupt(self.estimate(
                decision,
                false,
                [0.0; 3],
                0.0,
                [0.0; 3],
                (roll, pitch, self.config.initial_yaw_rad),
                [0.0; 3],
                None,
                None,
                None,
                None,
                None,
                None,
            )),
            integrity: Integrity::lost(IntegrityReason::Unaligned),
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn estimate(
        &self,
        decision: &Decision,
        aligned: bool,
        position_m: [f64; 3],
        distance_m: f64,
        velocity_mps: [f64; 3],
        (roll, pitch, yaw): (f64, f64, f64),
        position_sigma_m: [f64; 3],
        height_m: Option<f64>,
        yaw_sigma_deg: Option<f64>,
        attitude_sigma_deg: Option<[f64; 3]>,
        tilt_sigma_deg: Option<[f64; 2]>,
        smoothed_push: Option<Vec<TrackPoint>>,
        odometer_scale: Option<(f64, f64)>,
    ) -> ZuptEstimate {
        let s = &decision.statistics;
        let g = &decision.thresholds;
        let ratio = |t: f64, gamma: f64| {
            if gamma > 0.0 {
                t / gamma
            } else {
                f64::INFINITY
            }
        };
        ZuptEstimate {
            zv: decision.zv,
            position_m,
            distance_m,
            velocity_mps,
            pitch_deg: deg(pitch),
            roll_deg: deg(roll),
            yaw_deg: deg(yaw).rem_euclid(360.0),
            aligned,
            position_sigma_m,
            height_m,
            odometer_m: self.odometer.map(|(_, d)| d),
            mv_ratio: ratio(s.mv, g.mv),
            are_ratio: ratio(s.are, g.are),
            shoe_ratio: ratio(s.shoe, g.shoe),
            mag_ratio: ratio(s.mag, g.mag),
            yaw_sigma_deg,
            attitude_sigma_deg,
            pitch_sigma_deg: tilt_sigma_deg.map(|[pitch, _]| pitch),
            roll_sigma_deg: tilt_sigma_deg.map(|[_, roll]| roll),
            smoothed_push,
            odometer_scale: odometer_scale.map(|(scale, _)| scale),
            odometer_scale_sigma: odometer_scale.map(|(_, sigma)| sigma),
        }
    }

    /// Static coarse alignment on a still window.
    fn align(&self, statistics: &Statistics, sample: ImuSample) -> Navigation {
        let c = &self.config;
        let mean = if statistics.mean_accel_mps2.norm() > 0.0 {
            statistics.mean_accel_mps2
        } else {
            sample.accel_mps2
        };
        let (roll, pitch) = level(&mean);
        let attitude = attitude_from_euler(roll, pitch, c.initial_yaw_rad);
        // Levelling absorbs the horizontal accelerometer biases into tilt:
        // its error is about σ_ba / g.
        let g = c.pipeline.noise.gravity_mps2;
        let tilt_sigma = (c.accel_bias_sigma_mps2 / g).max(1e-5);
        let filter = ErrorStateFilter::new(
            [
                V3::repeat(1e-3),
                V3::repeat(c.zupt_sigma_mps),
                V3::new(tilt_sigma, tilt_sigma, c.initial_yaw_sigma_rad.max(1e-6)),
                V3::repeat(c.accel_bias_sigma_mps2.max(1e-7)),
                V3::repeat(c.gyro_bias_sigma_rad_per_s.max(1e-10)),
                V3::new(
                    c.odometer_scale_sigma.max(1e-9),
                    c.odometer_axis_sigma_rad.max(1e-9),
                    c.odometer_axis_sigma_rad.max(1e-9),
                ),
            ],
            c.process_noise,
        );
        Navigation {
            state: NavState::at_rest(attitude),
            filter,
            accel_bias_mps2: V3::zeros(),
            gyro_bias_rad_per_s: V3::zeros(),
            ins_distance_m: 0.0,
            ins_distance_history: VecDeque::from([(sample.t, 0.0)]),
            previous: Some(sample),
            interval_s: 0.0,
            force_integral: V3::zeros(),
            rate_integral: V3::zeros(),
            interval_still: true,
            zaru_noise: ZaruNoise::default(),
            distance_m: 0.0,
            push: None,
            height_datum_m: None,
            pending_height_m: None,
            pending_odometer: None,
            odometer: OdometerModel::default(),
            unverified_m: V3::zeros(),
            odometer_origin: None,
            odometer_disagreement_m: 0.0,
            odometer_slipped_m: 0.0,
            newest_count_m: None,
            slipped_total_m: 0.0,
            ins_push: None,
            speed_implausible: false,
            odometer_refused_from_t: None,
            odometer_refused_t: None,
        }
    }
}

/// Passes the decision on the reading at `t` through the rest check: a
/// called rest it refuses becomes moving, counted by the reason; a reading
/// called moving ends the check's run. `velocity` is `None` before
/// alignment.
fn check_rest(
    config: &RestCheckConfig,
    rest_check: &mut RestCheck,
    stats: &mut ZuptStats,
    t: f64,
    velocity: Option<Velocity<'_>>,
    decision: &mut Decision,
) {
    if !decision.zv {
        rest_check.moving();
        return;
    }
    match rest_check.judge(config, t, velocity) {
        None => return,
        Some(Refusal::Odometer) => stats.rests_refused_odometer += 1,
        Some(Refusal::Velocity | Refusal::StillMoving) => stats.rests_refused_velocity += 1,
    }
    decision.zv = false;
}

/// A position σ widened by the creep a rest no odometer confirmed may
/// hide: the error lies anywhere between none and the whole bound
/// `unconfirmed_m` (a creep at up to the fastest speed), whose RMS about
/// the estimate is the bound over √3.
fn with_creep_bound(sigma: &V3, unconfirmed_m: &V3) -> V3 {
    let creep = unconfirmed_m / 3f64.sqrt();
    sigma.zip_map(&creep, |s, c| (s * s + c * c).sqrt())
}

/// 1σ of pitch and roll, rad, from the attitude covariance (errors about
/// north, east, down) at heading `yaw`: pitch turns about the level right
/// axis (−sin ψ, cos ψ, 0), roll about the level forward axis (cos ψ,
/// sin ψ, 0); σ² = uᵀ P_φ u for each.
fn tilt_sigma(p: &eskf::Covariance, yaw: f64) -> [f64; 2] {
    let p_att = p.fixed_view::<2, 2>(ATT, ATT);
    let (sin, cos) = yaw.sin_cos();
    let along = |u: nalgebra::Vector2<f64>| (u.transpose() * p_att * u)[(0, 0)].max(0.0).sqrt();
    [
        along(nalgebra::Vector2::new(-sin, cos)),
        along(nalgebra::Vector2::new(cos, sin)),
    ]
}

/// A displacement projected on the body's forward axis.
fn along_track(state: &NavState, displacement_m: &V3) -> f64 {
    let forward = state.attitude * V3::x();
    displacement_m.dot(&forward)
}

impl Navigation {
    /// Keeps the INS distance at `t` (every [`INS_DISTANCE_STEP_S`], the
    /// newest always), over the last [`ODOMETER_MAX_GAP_S`] and a second.
    fn record_ins_distance(&mut self, t: f64) {
        let entry = (t, self.ins_distance_m);
        let history = &mut self.ins_distance_history;
        // The newest entry moves on until it is a step past the one before.
        let before_newest_t = history
            .len()
            .checked_sub(2)
            .and_then(|k| history.get(k))
            .map(|&(before_t, _)| before_t);
        match history.back_mut() {
            Some(newest) if before_newest_t.is_some_and(|b| t - b < INS_DISTANCE_STEP_S) => {
                *newest = entry
            }
            _ => history.push_back(entry),
        }
        while history
            .front()
            .is_some_and(|&(oldest_t, _)| oldest_t < t - ODOMETER_MAX_GAP_S - 1.0)
        {
            history.pop_front();
        }
    }

    /// The INS distance at `t`, linear between the entries kept; `None`
    /// outside them (before alignment or a gap, or not integrated yet).
    fn ins_distance_at(&self, t: f64) -> Option<f64> {
        let history = &self.ins_distance_history;
        let after = history.partition_point(|&(entry_t, _)| entry_t < t);
        let &(t1, d1) = history.get(after)?;
        if t1 == t {
            return Some(d1);
        }
        let &(t0, d0) = history.get(after.checked_sub(1)?)?;
        Some(d0 + (d1 - d0) * (t - t0) / (t1 - t0))
    }

    /// True while state and covariance are finite numbers.
    fn is_finite(&self) -> bool {
        self.state.position_m.iter().all(|x| x.is_finite())
            && self.state.velocity_mps.iter().all(|x| x.is_finite())
            && self.state.attitude.coords.iter().all(|x| x.is_finite())
            && self.distance_m.is_finite()
            && self.filter.is_sane()
            // A scale of zero or less would divide the count by it.
            && self.odometer.scale() > 0.1
            && self.odometer.axis_rad.iter().all(|x| x.is_finite())
    }

    /// A filter epoch: propagate the covariance, make the updates that are
    /// due, feed the errors back. Returns the track of a push it ends,
    /// smoothed.
    /// `rest_confirmed`: an odometer stood still over its window.
    fn epoch(
        &mut self,
        config: &ZuptConfig,
        t: f64,
        zv: bool,
        rest_confirmed: bool,
        stats: &mut ZuptStats,
    ) -> Option<Vec<TrackPoint>> {
        // The bias subtracted from this interval's rates (updates below
        // may change it).
        let gyro_bias_in_interval = self.gyro_bias_rad_per_s;
        let site = &config.site;
        let (lat, height) = site.at(&self.state.position_m);
        let (meridian, transverse) = radii_m(lat);
        let radius = (meridian * transverse).sqrt() + height;
        let c_bn = self.state.attitude.to_rotation_matrix().into_inner();
        let dynamics = Dynamics {
            specific_force_n: self.force_integral / self.interval_s,
            c_bn,
            earth_rate_n: earth_rate_n(lat),
            transport_rate_n: site
                .transport_rate_n(&self.state.position_m, &self.state.velocity_mps),
            gravity_gradient: 2.0 * normal_gravity_mps2(lat, height) / radius,
        };
        let phi = self.filter.propagate(&dynamics, self.interval_s);
        // A push not begun is anchored afresh at the end of a confirmed
        // still epoch: its propagation would be thrown away.
        let anchored_again = zv && self.interval_still && rest_confirmed && config.odometer_aiding;
        if let Some(push) = &mut self.ins_push
            && (!anchored_again || push.moved())
        {
            push.epoch(&dynamics, config.zupt_sigma_mps);
        }
        if let Some(push) = &mut self.push {
            push.propagated(&phi, &self.filter.p);
        }
        let mean_rate = self.rate_integral / self.interval_s;
        let interval_s = self.interval_s;
        let interval_still = self.interval_still;
        self.interval_s = 0.0;
        self.force_integral = V3::zeros();
        self.rate_integral = V3::zeros();
        self.interval_still = true;
        // On the velocity the interval ended with, before this epoch's
        // updates: the epoch that ends a run-away still counts its advance.
        self.bound_speed(config, interval_s);

        // The gate is on the squared Mahalanobis distance.
        let gate = (config.aid_gate_sigma > 0.0).then(|| config.aid_gate_sigma.powi(2));
        if zv {
            let r = SMatrix::<f64, 3, 3>::identity() * config.zupt_sigma_mps.powi(2);
            let result = self
                .filter
                .update(&zupt_matrix(), &self.state.velocity_mps, &r, None);
            self.apply(result, stats, |s| s.zupt_updates += 1);
            if !rest_confirmed {
                self.unverified_m +=
                    self.state.attitude * V3::x() * (config.max_speed_mps * interval_s);
            }
        }
        if zv && interval_still && config.zaru {
            // The mean rate over the interval: the gyro noise averages to
            // ARW²/T per axis, machinery vibration far less; the variance
            // is estimated from the rates ([`zaru_noise`]).
            let arw_variance = config.process_noise.gyro_arw.powi(2) / interval_s;
            // The raw mean (the bias estimate added back), so that the
            // updates' corrections of the bias are not taken for noise.
            let raw_mean_rate = mean_rate + gyro_bias_in_interval;
            if let Some(variance) = self.zaru_noise.still(&raw_mean_rate, arw_variance) {
                let c_bn = self.state.attitude.to_rotation_matrix().into_inner();
                let earth = dynamics.earth_rate_n;
                let innovation = mean_rate - c_bn.transpose() * earth;
                let settling = config.zaru_sigma_rad_per_s.powi(2);
                let r = SMatrix::<f64, 3, 3>::from_diagonal(&variance.add_scalar(settling));
                let result = self
                    .filter
                    .update(&zaru_matrix(&c_bn, &earth), &innovation, &r, None);
                self.apply(result, stats, |s| s.zaru_updates += 1);
            }
        } else {
            self.zaru_noise.interrupted();
        }
        if let Some(measured_m) = self.pending_height_m.take() {
            match self.height_datum_m {
                // The first height fixes the datum of the start point.
                None => self.height_datum_m = Some(measured_m + self.state.position_m.z),
                Some(datum) => {
                    let innovation =
                        SVector::<f64, 1>::new(datum - self.state.position_m.z - measured_m);
                    let r = SMatrix::<f64, 1, 1>::new(config.level_sigma_m.powi(2));
                    let result = self.filter.update(&height_matrix(), &innovation, &r, gate);
                    if result == Err(eskf::UpdateError::Gated) {
                        stats.heights_refused += 1;
                    } else {
                        self.apply(result, stats, |s| s.height_updates += 1);
                        // The level measured the height: no creep hides in it.
                        self.unverified_m.z = 0.0;
                    }
                }
            }
        }
        if let Some(fix) = self.pending_odometer.take()
            && config.odometer_aiding
            && let Some(origin) = self.odometer_origin
        {
            self.fuse_odometer(config, &fix, &origin, &c_bn, gate, t, stats);
        }
        if zv && interval_still && rest_confirmed && config.odometer_aiding {
            self.confirmed_rest(config, gate, stats);
        }
        if config.smooth_pushes {
            self.record_push(config, zv && interval_still, stats)
        } else {
            None
        }
    }

    /// The machine cannot go faster than its declared `max_speed_mps`.
    /// An epoch whose speed is beyond it by more than
    /// [`SPEED_BOUND_SIGMAS`] σ of the filter's velocity along it has run
    /// away (a tilt or a bias a rest update mistook, a push called a
    /// rest): the estimate is `lost` (`speed_implausible`), and what the
    /// INS advanced over the `interval_s` is added to the bound the
    /// position's σ grows by ([`with_creep_bound`]: none of it is
    /// confirmed, and the machine's own advance, at most `max_speed_mps`,
    /// is a small part of it), so that the position after it says how
    /// little it is worth.
    fn bound_speed(&mut self, config: &ZuptConfig, interval_s: f64) {
        let velocity = self.state.velocity_mps;
        let speed_mps = velocity.norm();
        self.speed_implausible = false;
        if speed_mps <= config.max_speed_mps {
            return;
        }
        let direction = velocity / speed_mps;
        let sigma_mps = self.filter.variance_along(VEL, &direction).sqrt();
        if speed_mps - SPEED_BOUND_SIGMAS * sigma_mps > config.max_speed_mps {
            self.speed_implausible = true;
            // Away from zero, with the sign the bound's other terms take
            // (the axis's: the creep and the odometer's disagreement).
            let run_m = direction * (speed_mps * interval_s);
            let forward = self.state.attitude * V3::x();
            for k in 0..3 {
                let sign = if self.unverified_m[k] != 0.0 {
                    self.unverified_m[k].signum()
                } else if forward[k] != 0.0 {
                    forward[k].signum()
                } else {
                    1.0
                };
                self.unverified_m[k] += sign * run_m[k].abs();
            }
        }
    }

    /// Takes an odometer reading of `counted_m` at `t` (`previous`: the
    /// one before): the first after alignment is the origin the count is
    /// compared from, each later one waits for the next epoch; the two
    /// distances' disagreement is updated. An advance beyond `moved_m`
    /// over epochs all still contradicts the push being measured.
    fn odometer_read(
        &mut self,
        previous: Option<(f64, f64)>,
        t: f64,
        counted_m: f64,
        moved_m: f64,
    ) {
        if let (Some((_, previous_m)), Some(push)) = (previous, &mut self.ins_push) {
            push.counted(counted_m - previous_m, moved_m);
        }
        let engine_m = self.engine_distance_at(t);
        let interval = previous
            .filter(|&(prev_t, _)| t - prev_t <= ODOMETER_MAX_GAP_S)
            .and_then(|(prev_t, prev_m)| {
                Some(OdometerInterval {
                    advance_m: counted_m - prev_m,
                    ins_advance_m: self.ins_distance_at(t)? - self.ins_distance_at(prev_t)?,
                    dt_s: t - prev_t,
                })
            });
        // A reading not fused yet: its interval and this one's are
        // checked for a slip as one.
        let interval = match self.pending_odometer.take() {
            None => interval,
            Some(waiting) => waiting
                .interval
                .zip(interval)
                .map(|(a, b)| OdometerInterval {
                    advance_m: a.advance_m + b.advance_m,
                    ins_advance_m: a.ins_advance_m + b.ins_advance_m,
                    dt_s: a.dt_s + b.dt_s,
                }),
        };
        self.newest_count_m = Some(counted_m);
        let origin = match self.odometer_origin {
            Some(origin) => {
                self.pending_odometer = Some(OdometerFix {
                    t,
                    counted_m,
                    interval,
                });
                origin
            }
            None => *self.odometer_origin.insert(OdometerOrigin {
                counted_m,
                engine_m,
                sigma_m: self.along_variance_m2().sqrt(),
            }),
        };
        self.odometer_disagreement_m =
            (counted_m - origin.counted_m) / self.odometer.scale() - (engine_m - origin.engine_m);
    }

    /// The engine's along-track distance at `t` (at most the INS history
    /// ago): now's less what the INS advanced since, m.
    fn engine_distance_at(&self, t: f64) -> f64 {
        match self.ins_distance_at(t) {
            Some(at_m) => self.distance_m - (self.ins_distance_m - at_m),
            None => self.distance_m,
        }
    }

    /// The filter's variance of the position along the machine's axis, m².
    fn along_variance_m2(&self) -> f64 {
        let forward = self.state.attitude * V3::x();
        self.filter.variance_along(POS, &forward)
    }

    /// Fuses an odometer reading (the monitor first): an interval whose
    /// count exceeds the scale times the INS's advance by more than
    /// `aid_gate_sigma` σ (the count's noise twice, the INS's velocity σ
    /// over the interval, the scale's σ) is not fused, and the origin
    /// moves on by the part of the excess a wheel can have slipped
    /// ([`OdometerInterval::possible_slip_m`]); otherwise the count since the origin
    /// is compared with the scale times the engine's advance since then
    /// (Eq. of [`odometer_matrix`]) with zero speed across the odometer's
    /// axis, gated as a whole.
    #[allow(clippy::too_many_arguments)]
    fn fuse_odometer(
        &mut self,
        config: &ZuptConfig,
        fix: &OdometerFix,
        origin: &OdometerOrigin,
        c_bn: &nalgebra::Matrix3<f64>,
        gate: Option<f64>,
        t: f64,
        stats: &mut ZuptStats,
    ) {
        let scale = self.odometer.scale();
        let forward = self.state.attitude * V3::x();
        let slip = fix.interval.and_then(|interval| {
            let excess_m = interval.excess_m(scale);
            let along_v = self.filter.variance_along(VEL, &forward);
            let p_s = self.filter.p[(ODOMETER, ODOMETER)].max(0.0);
            let sigma_m = (2.0 * config.odometer_distance_sigma_m.powi(2)
                + scale * scale * along_v * interval.dt_s.powi(2)
                + p_s * interval.ins_advance_m.powi(2))
            .sqrt();
            (gate.is_some() && excess_m.abs() > config.aid_gate_sigma * sigma_m)
                .then_some((excess_m, interval))
        });
        if let Some((excess_m, interval)) = slip {
            stats.odometer_refused += 1;
            let slipped_m = interval.possible_slip_m(scale, config.max_speed_mps);
            self.odometer_refused(t, slipped_m, excess_m / scale / interval.dt_s);
            return;
        }
        // The count first: it corrects position and velocity only (a
        // platform tilted, or a bias moved, to fit the count would carry
        // the scale's error into the next push's own measurement,
        // [`odometer_scale`]).
        let velocity_b = self.state.attitude.inverse() * self.state.velocity_mps;
        let counted_m = fix.counted_m - origin.counted_m;
        let travelled_m = self.engine_distance_at(fix.t) - origin.engine_m;
        let innovation = self
            .odometer
            .innovation(travelled_m, counted_m, &velocity_b);
        let h = odometer_matrix(c_bn, &self.state.velocity_mps, &self.odometer, travelled_m);
        let r = SMatrix::<f64, 1, 1>::new(
            config.odometer_distance_sigma_m.powi(2) + origin.sigma_m.powi(2),
        );
        let result = self.filter.update_considering(
            &h.fixed_rows::<1>(0).into_owned(),
            &SVector::<f64, 1>::new(innovation.x),
            &r,
            gate,
            ATT..eskf::N,
        );
        if result == Err(eskf::UpdateError::Gated) {
            stats.odometer_refused += 1;
            let speed_mps = fix
                .interval
                .map_or(0.0, |i| i.excess_m(scale) / scale / i.dt_s);
            self.odometer_refused(t, 0.0, speed_mps);
            return;
        }
        self.odometer_refused_from_t = None;
        self.odometer_slipped_m = 0.0;
        self.apply(result, stats, |s| s.odometer_updates += 1);
        // Then zero speed across the axis, on the state the count left:
        // it tells the velocity and the platform's attitude.
        let velocity_b = self.state.attitude.inverse() * self.state.velocity_mps;
        let across = self.odometer.innovation(0.0, 0.0, &velocity_b);
        let h = odometer_matrix(c_bn, &self.state.velocity_mps, &self.odometer, 0.0);
        let result = self.filter.update(
            &h.fixed_rows::<2>(1).into_owned(),
            &nalgebra::Vector2::new(across.y, across.z),
            &(SMatrix::<f64, 2, 2>::identity() * config.odometer_sigma_mps.powi(2)),
            gate,
        );
        if result != Err(eskf::UpdateError::Gated) {
            self.apply(result, stats, |_| {});
        }
    }

    /// At a still epoch the odometer confirms: a push since the last such
    /// rest is measured and its scale fused ([`odometer_scale`]), and the
    /// next push is anchored here.
    fn confirmed_rest(&mut self, config: &ZuptConfig, gate: Option<f64>, stats: &mut ZuptStats) {
        let Some(counted_m) = self.newest_count_m.map(|c| c - self.slipped_total_m) else {
            return;
        };
        if self.ins_push.as_ref().is_some_and(InsPush::moved) {
            let forward = self.state.attitude * V3::x();
            if let Some(measured) = self
                .ins_push
                .as_ref()
                .and_then(|push| push.measure(counted_m, &forward))
            {
                self.fuse_push_scale(config, &measured, gate, stats);
            }
        }
        // Anchored afresh at every confirmed rest (after the update: from
        // what it says), so from the newest calibration before the push.
        self.ins_push = Some(self.push_anchor(counted_m));
    }

    /// A push anchored here, the count `counted_m`.
    fn push_anchor(&self, counted_m: f64) -> InsPush {
        InsPush::anchored(
            counted_m,
            &self.state,
            &self.filter,
            &self.accel_bias_mps2,
            &self.gyro_bias_rad_per_s,
        )
    }

    /// Updates the scale with the one a measured push says.
    fn fuse_push_scale(
        &mut self,
        config: &ZuptConfig,
        measured: &MeasuredPush,
        gate: Option<f64>,
        stats: &mut ZuptStats,
    ) {
        let Some((scale, sigma)) =
            measured.scale(self.odometer.scale(), config.odometer_distance_sigma_m)
        else {
            return;
        };
        let innovation = SVector::<f64, 1>::new(self.odometer.scale() - scale);
        let r = SMatrix::<f64, 1, 1>::new(sigma * sigma);
        let result = self.filter.update_considering(
            &scale_matrix(),
            &innovation,
            &r,
            gate,
            // The push started from the filter's attitude and biases:
            // its error shares theirs, so it moves none of them.
            (ATT..ODOMETER).chain(ODOMETER + 1..eskf::N),
        );
        if result == Err(eskf::UpdateError::Gated) {
            stats.odometer_scale_refused += 1;
        } else {
            self.apply(result, stats, |s| s.odometer_scale_pushes += 1);
        }
    }

    /// The monitor of the odometer against the INS, at an odometer reading
    /// refused at `t`: a slip of `slipped_m` (0 for a count the gate
    /// refused) moves the origin on, so the count after it compares again.
    /// Refused for [`ODOMETER_LOCKOUT_S`] or longer (longer than a wheel
    /// slips), the INS is taken to have drifted instead: the slips of the
    /// run are taken back and the position's and velocity's covariance
    /// along the axis open by the disagreement (`speed_mps` the newest
    /// interval's, in the engine's metres per second), so that the next reading is fused rather than refused
    /// for the rest of the drive.
    fn odometer_refused(&mut self, t: f64, slipped_m: f64, speed_mps: f64) {
        let scale = self.odometer.scale();
        if let Some(origin) = &mut self.odometer_origin {
            origin.counted_m += slipped_m;
            self.odometer_disagreement_m -= slipped_m / scale;
            self.odometer_slipped_m += slipped_m;
            self.slipped_total_m += slipped_m;
        }
        let from_t = *self.odometer_refused_from_t.get_or_insert(t);
        self.odometer_refused_t = Some(t);
        if t - from_t >= ODOMETER_LOCKOUT_S {
            let forward = self.state.attitude * V3::x();
            let slipped_m = std::mem::take(&mut self.odometer_slipped_m);
            if let Some(origin) = &mut self.odometer_origin {
                origin.counted_m -= slipped_m;
                self.odometer_disagreement_m += slipped_m / scale;
                self.slipped_total_m -= slipped_m;
            }
            // The push in measurement counted without those slips.
            self.ins_push = None;
            let along = forward * forward.transpose();
            let mut p_p = self.filter.p.fixed_view_mut::<3, 3>(POS, POS);
            p_p += along * self.odometer_disagreement_m.powi(2);
            let mut p_v = self.filter.p.fixed_view_mut::<3, 3>(VEL, VEL);
            p_v += along * speed_mps.powi(2);
            self.odometer_refused_from_t = None;
        }
    }

    /// `degraded` (`odometer_disagrees`) within [`ODOMETER_LOCKOUT_S`] of
    /// an odometer interval the gate refused, or while the odometer's
    /// distance and the engine's disagree by more than
    /// [`ODOMETER_DISAGREE_SIGMAS`] σ of what each may be off by (the
    /// filter's along-track σ, the odometer's scale error over its
    /// distance, [`ODOMETER_DISAGREE_FLOOR_M`]); else `ok`.
    fn integrity(&self, t: f64) -> Integrity {
        if self.speed_implausible {
            return Integrity::lost(IntegrityReason::SpeedImplausible);
        }
        let refused = self
            .odometer_refused_t
            .is_some_and(|refused_t| t - refused_t < ODOMETER_LOCKOUT_S);
        let along_variance = self.along_variance_m2();
        let scale_m = self.filter.p[(ODOMETER, ODOMETER)].max(0.0).sqrt() * self.distance_m.abs();
        let sigma_m = (along_variance + scale_m.powi(2) + ODOMETER_DISAGREE_FLOOR_M.powi(2)).sqrt();
        if refused || self.odometer_disagreement_m.abs() > ODOMETER_DISAGREE_SIGMAS * sigma_m {
            Integrity::degraded(IntegrityReason::OdometerDisagrees)
        } else {
            Integrity::OK
        }
    }

    /// Keeps the epoch just made in the push record; at the first still
    /// epoch after a push, smooths it (see [`smoother`]) and returns its track.
    fn record_push(
        &mut self,
        config: &ZuptConfig,
        still: bool,
        stats: &mut ZuptStats,
    ) -> Option<Vec<TrackPoint>> {
        let t = self.previous?.t;
        let point = Point {
            t,
            position_m: self.state.position_m,
            distance_m: self.distance_m,
            forward: self.state.attitude * V3::x(),
            p_post: self.filter.p,
        };
        let mut track = None;
        if still {
            if let Some(mut push) = self.push.take()
                && push.has_moved()
            {
                push.end_epoch(point.clone(), true);
                track = push.smooth();
                match track {
                    Some(_) => stats.pushes_smoothed += 1,
                    None => stats.updates_failed += 1,
                }
            }
            self.push = Some(PushRecord::anchored(point));
        } else if let Some(push) = &mut self.push {
            push.end_epoch(point, false);
            if push.span_s() > config.smooth_max_push_s {
                self.push = None;
                stats.pushes_too_long += 1;
            }
        }
        track
    }

    /// Closed-loop feedback of an estimated error state.
    fn apply(
        &mut self,
        result: Result<eskf::ErrorState, eskf::UpdateError>,
        stats: &mut ZuptStats,
        count: impl FnOnce(&mut ZuptStats),
    ) {
        let Ok(dx) = result else {
            stats.updates_failed += 1;
            return;
        };
        count(stats);
        if let Some(push) = &mut self.push {
            push.fed_back(&dx);
        }
        let position_correction = -V3::new(dx[POS], dx[POS + 1], dx[POS + 2]);
        self.distance_m += along_track(&self.state, &position_correction);
        eskf::feed_back(
            &dx,
            &mut self.state,
            &mut self.accel_bias_mps2,
            &mut self.gyro_bias_rad_per_s,
        );
        self.odometer.correct(&dx);
    }
}

/// The `zupt` engine as the registry lists it.
pub struct Zupt;

impl EngineDescriptor for Zupt {
    const SUMMARY: &'static str = "FOG strapdown INS: position and attitude, corrected at every zero-velocity rest and by the level";
    const SENSORS: &'static [SensorKind] =
        &[SensorKind::Imu, SensorKind::Level, SensorKind::Odometer];
    const RETIRED: &'static [Retired] = &[];
    type Params = ZuptParams;
    type Engine = ZuptEngine;
    type Estimate = ZuptEstimate;
    type Model = NoModel;

    fn create(params: Params) -> Result<ZuptEngine, ParamError> {
        ZuptEngine::new(params)
    }
    fn restore(snapshot: serde_json::Value) -> Result<ZuptEngine, SnapshotError> {
        ZuptEngine::restore(snapshot)
    }
}

impl Engine for ZuptEngine {
    fn kind(&self) -> EngineKind {
        EngineKind::Zupt
    }

    fn feed(&mut self, reading: &Reading, out: &mut Vec<EngineOutput>) {
        match &reading.data {
            SensorData::Imu {
                accel_mps2,
                gyro_dps,
            } => self.on_imu(ImuSample::new(reading.t, accel_mps2, gyro_dps), out),
            SensorData::Level { height_m } => {
                Self::queue_aid(&mut self.levels, &mut self.stats, reading.t, *height_m);
            }
            SensorData::Odometer { distance_m } => {
                Self::queue_aid(&mut self.odometers, &mut self.stats, reading.t, *distance_m);
            }
            _ => {}
        }
    }

    fn flush(&mut self, out: &mut Vec<EngineOutput>) {
        self.end_stream(out);
    }

    fn params(&self) -> &Params {
        &self.params
    }

    fn snapshot(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }
}

#[cfg(test)]
mod tests;
