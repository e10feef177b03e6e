//! The error-state Kalman filter (Zhang et al. 2024, Sec. 4), its 15
//! states δx = [δp, δv, φ, δb_a, δb_g] and three of the odometer's
//! (issue 58): its scale error δs and the small angles δa_y, δa_z of its
//! axis toward the body's y and z (mounting misalignment), constants the
//! zero-velocity-bounded INS makes observable. Closed-loop feedback, so
//! the error state is zero after every correction and only the
//! covariance is propagated.
//!
//! Conventions: δp = p̂ − p, δv = v̂ − v, Ĉ = (I − [φ×])·C (φ is the
//! attitude error in the navigation frame), δb = b − b̂. The paper's F
//! leaves out the Earth and transport rates; the Earth-rate terms are
//! larger than a 0.5 °/h bias (docs/papers.md), so the error dynamics
//! here are the full local-level ones (gravity gradient
//! included):
//! - δṗ = δv
//! - δv̇ = [fⁿ×]·φ − [(2ω_ie + ω_en)×]·δv + Ĉ·δb_a + (2g/R)·δp_D·e_D + Ĉ·w_a
//! - φ̇ = −[ω_in×]·φ − Ĉ·δb_g − Ĉ·w_g
//! - δḃ_a = w_ba, δḃ_g = w_bg (random walks)
//! - δṡ = 0, δȧ = 0 (the odometer's calibration and mounting)

use nalgebra::{Matrix3, SMatrix, SVector};
use serde::{Deserialize, Serialize};

use super::strapdown::NavState;
use crate::fusion::geometry::{V3, skew};

/// Number of error states.
pub const N: usize = 18;
/// Offsets of the state blocks.
pub const POS: usize = 0;
pub const VEL: usize = 3;
pub const ATT: usize = 6;
pub const ACCEL_BIAS: usize = 9;
pub const GYRO_BIAS: usize = 12;
/// The odometer block: scale error, then its axis's angles toward body
/// y and z.
pub const ODOMETER: usize = 15;

/// The covariance.
pub type Covariance = SMatrix<f64, N, N>;
/// An error-state vector.
pub type ErrorState = SVector<f64, N>;

/// Spectral densities of the process noise (continuous time).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ProcessNoise {
    /// Velocity random walk, (m/s)/√s.
    pub accel_vrw: f64,
    /// Angle random walk, rad/√s.
    pub gyro_arw: f64,
    /// Accelerometer bias random walk, (m/s²)/√s.
    pub accel_bias_rw: f64,
    /// Gyro bias random walk, (rad/s)/√s.
    pub gyro_bias_rw: f64,
}

/// What the error dynamics depend on over one propagation interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dynamics {
    /// Mean specific force in NED, m/s².
    pub specific_force_n: V3,
    /// Body to NED.
    pub c_bn: Matrix3<f64>,
    /// ω_ieⁿ and ω_enⁿ, rad/s.
    pub earth_rate_n: V3,
    pub transport_rate_n: V3,
    /// 2g/R, s⁻²: the vertical gravity gradient.
    pub gravity_gradient: f64,
}

/// Why an update was not applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum UpdateError {
    #[error("innovation covariance is not positive definite")]
    Singular,
    #[error("innovation fails the gate")]
    Gated,
}

/// The covariance of the error state; see the module documentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorStateFilter {
    pub p: Covariance,
    pub noise: ProcessNoise,
}

impl ErrorStateFilter {
    /// A filter with a diagonal initial covariance given as standard
    /// deviations per block: position (m), velocity (m/s), attitude (rad,
    /// as [roll/pitch, roll/pitch, heading] about north, east, down),
    /// accel bias (m/s²), gyro bias (rad/s), odometer (scale error as a
    /// fraction, axis angles in rad).
    pub fn new(initial_sigma: [V3; 6], noise: ProcessNoise) -> ErrorStateFilter {
        let mut p = Covariance::zeros();
        for (block, sigma) in initial_sigma.iter().enumerate() {
            for axis in 0..3 {
                p[(3 * block + axis, 3 * block + axis)] = sigma[axis] * sigma[axis];
            }
        }
        ErrorStateFilter { p, noise }
    }

    /// The continuous-time system matrix F.
    pub fn system_matrix(d: &Dynamics) -> Covariance {
        let mut f = Covariance::zeros();
        f.fixed_view_mut::<3, 3>(POS, VEL)
            .copy_from(&Matrix3::identity());
        f.fixed_view_mut::<3, 3>(VEL, VEL)
            .copy_from(&-skew(&(2.0 * d.earth_rate_n + d.transport_rate_n)));
        f.fixed_view_mut::<3, 3>(VEL, ATT)
            .copy_from(&skew(&d.specific_force_n));
        f.fixed_view_mut::<3, 3>(VEL, ACCEL_BIAS).copy_from(&d.c_bn);
        f[(VEL + 2, POS + 2)] = d.gravity_gradient;
        f.fixed_view_mut::<3, 3>(ATT, ATT)
            .copy_from(&-skew(&(d.earth_rate_n + d.transport_rate_n)));
        f.fixed_view_mut::<3, 3>(ATT, GYRO_BIAS).copy_from(&-d.c_bn);
        f
    }

    /// Propagates the covariance over `dt_s`: Φ = I + F·dt + (F·dt)²/2,
    /// P = Φ·P·Φᵀ + Q_d with Q_d by the trapezoidal rule,
    /// ½(Φ·Q·Φᵀ + Q)·dt.
    /// Propagates over `dt_s`; returns the transition Φ used.
    pub fn propagate(&mut self, d: &Dynamics, dt_s: f64) -> Covariance {
        let f_dt = Self::system_matrix(d) * dt_s;
        let phi = Covariance::identity() + f_dt + f_dt * f_dt * 0.5;
        let n = &self.noise;
        let mut q = ErrorState::zeros();
        for axis in 0..3 {
            q[VEL + axis] = n.accel_vrw * n.accel_vrw;
            q[ATT + axis] = n.gyro_arw * n.gyro_arw;
            q[ACCEL_BIAS + axis] = n.accel_bias_rw * n.accel_bias_rw;
            q[GYRO_BIAS + axis] = n.gyro_bias_rw * n.gyro_bias_rw;
        }
        // Q is diagonal: Φ·Q is Φ's columns scaled, one product less.
        let mut phi_q = phi;
        for (mut column, q_j) in phi_q.column_iter_mut().zip(q.iter()) {
            column *= *q_j;
        }
        let q_d = (phi_q * phi.transpose() + Covariance::from_diagonal(&q)) * (0.5 * dt_s);
        self.p = phi * self.p * phi.transpose() + q_d;
        self.symmetrise();
        phi
    }

    /// Adds process noise for a span with no inertial data (a gap): the
    /// velocity and attitude uncertainty grow as the noise densities say.
    pub fn inflate(&mut self, dt_s: f64) {
        let n = &self.noise;
        for axis in 0..3 {
            self.p[(VEL + axis, VEL + axis)] += n.accel_vrw * n.accel_vrw * dt_s;
            self.p[(ATT + axis, ATT + axis)] += n.gyro_arw * n.gyro_arw * dt_s;
            self.p[(ACCEL_BIAS + axis, ACCEL_BIAS + axis)] += n.accel_bias_rw.powi(2) * dt_s;
            self.p[(GYRO_BIAS + axis, GYRO_BIAS + axis)] += n.gyro_bias_rw.powi(2) * dt_s;
        }
    }

    /// A measurement update z = H·δx + noise(R), with `innovation` = the
    /// predicted measurement minus the measured one. Joseph form. Returns
    /// the estimated error state, which the caller feeds back. With a
    /// `gate`, an innovation whose squared Mahalanobis distance exceeds it
    /// is refused. The odometer's scale is only considered here: it is
    /// learned from whole pushes alone ([`super::odometer_scale`]), which
    /// update it with [`Self::update_considering`].
    pub fn update<const M: usize>(
        &mut self,
        h: &SMatrix<f64, M, N>,
        innovation: &SVector<f64, M>,
        r: &SMatrix<f64, M, M>,
        gate: Option<f64>,
    ) -> Result<ErrorState, UpdateError> {
        self.update_considering(h, innovation, r, gate, ODOMETER..ODOMETER + 1)
    }

    /// [`Self::update`] with the states `consider` only considered
    /// (Schmidt–Kalman): their uncertainty widens the innovation's
    /// covariance and is carried into the others' through the
    /// correlations, but this measurement does not move them (their gain
    /// rows are zero; the Joseph form holds for any gain).
    pub fn update_considering<const M: usize>(
        &mut self,
        h: &SMatrix<f64, M, N>,
        innovation: &SVector<f64, M>,
        r: &SMatrix<f64, M, M>,
        gate: Option<f64>,
        consider: impl IntoIterator<Item = usize>,
    ) -> Result<ErrorState, UpdateError> {
        let ph_t = self.p * h.transpose();
        let s = h * ph_t + r;
        let s_inv = s.cholesky().ok_or(UpdateError::Singular)?.inverse();
        if let Some(gate) = gate
            && (innovation.transpose() * s_inv * innovation)[(0, 0)] > gate
        {
            return Err(UpdateError::Gated);
        }
        let mut k = ph_t * s_inv;
        for state in consider {
            k.row_mut(state).fill(0.0);
        }
        let i_kh = Covariance::identity() - k * h;
        self.p = i_kh * self.p * i_kh.transpose() + k * r * k.transpose();
        self.symmetrise();
        Ok(k * innovation)
    }

    /// Standard deviations of one block.
    pub fn sigma(&self, block: usize) -> V3 {
        V3::new(
            self.p[(block, block)].max(0.0).sqrt(),
            self.p[(block + 1, block + 1)].max(0.0).sqrt(),
            self.p[(block + 2, block + 2)].max(0.0).sqrt(),
        )
    }

    /// Variance of one block along the unit vector `direction` (uᵀ·P·u),
    /// never negative.
    pub fn variance_along(&self, block: usize, direction: &V3) -> f64 {
        let p_block = self.p.fixed_view::<3, 3>(block, block);
        (direction.transpose() * p_block * direction)[(0, 0)].max(0.0)
    }

    fn symmetrise(&mut self) {
        self.p = (self.p + self.p.transpose()) * 0.5;
    }

    /// True if every entry is finite and the diagonal is not negative.
    pub fn is_sane(&self) -> bool {
        self.p.iter().all(|x| x.is_finite()) && (0..N).all(|i| self.p[(i, i)] >= 0.0)
    }
}

/// Closed-loop feedback of the INS block of an estimated error state into
/// a navigation state and its bias estimates (δx = estimate − truth, so
/// each is corrected by subtracting its error; Ĉ = (I − [φ×])·C, so
/// C ≈ (I + [φ×])·Ĉ).
pub fn feed_back(
    dx: &ErrorState,
    state: &mut NavState,
    accel_bias_mps2: &mut V3,
    gyro_bias_rad_per_s: &mut V3,
) {
    let block = |at: usize| V3::new(dx[at], dx[at + 1], dx[at + 2]);
    state.position_m -= block(POS);
    state.velocity_mps -= block(VEL);
    state.attitude = nalgebra::UnitQuaternion::from_scaled_axis(block(ATT)) * state.attitude;
    *accel_bias_mps2 += block(ACCEL_BIAS);
    *gyro_bias_rad_per_s += block(GYRO_BIAS);
}

/// H of a zero-velocity update: the velocity error is measured directly,
/// H = [0 I 0 0 0] (the paper's Eq. for the ZUPT observation).
pub fn zupt_matrix() -> SMatrix<f64, 3, N> {
    let mut h = SMatrix::<f64, 3, N>::zeros();
    h.fixed_view_mut::<3, 3>(0, VEL)
        .copy_from(&Matrix3::identity());
    h
}

/// H of a zero-angular-rate update (ZARU): at rest the bias-corrected
/// gyro reads the Earth's rotation, ω̃ − b̂_g = Cᵀω_ie + δb_g + noise, and
/// with C ≈ (I + [φ×])Ĉ the innovation ω̃ − b̂_g − Ĉᵀω_ie =
/// Ĉᵀ[ω_ie×]φ + δb_g: every gyro bias, the vertical one (heading drift)
/// included, is seen at every rest.
pub fn zaru_matrix(c_bn: &Matrix3<f64>, earth_rate_n: &V3) -> SMatrix<f64, 3, N> {
    let mut h = SMatrix::<f64, 3, N>::zeros();
    h.fixed_view_mut::<3, 3>(0, ATT)
        .copy_from(&(c_bn.transpose() * skew(earth_rate_n)));
    h.fixed_view_mut::<3, 3>(0, GYRO_BIAS)
        .copy_from(&Matrix3::identity());
    h
}

/// H of a height update: ĥ − h = −δp_D.
pub fn height_matrix() -> SMatrix<f64, 1, N> {
    let mut h = SMatrix::<f64, 1, N>::zeros();
    h[(0, POS + 2)] = -1.0;
    h
}

/// H of a measurement of the odometer's scale error itself: ŝ − s = δs.
pub fn scale_matrix() -> SMatrix<f64, 1, N> {
    let mut h = SMatrix::<f64, 1, N>::zeros();
    h[(0, ODOMETER)] = 1.0;
    h
}

/// The odometer as the filter models it: its count is (1 + `scale_error`)
/// times the distance travelled along its axis, which leans from the
/// body's x by the small angles `axis_rad` toward y and z (the machine
/// moves along it, so across it the body's speed is zero).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct OdometerModel {
    pub scale_error: f64,
    pub axis_rad: [f64; 2],
}

impl OdometerModel {
    /// 1 + ŝ.
    pub fn scale(&self) -> f64 {
        1.0 + self.scale_error
    }

    /// The innovation of an odometer reading (predicted − measured): the
    /// count `counted_m` since the origin against the scale times the
    /// engine's along-track advance since then `travelled_m`, and zero
    /// speed across the odometer's axis for the body velocity now
    /// `velocity_b`.
    pub fn innovation(&self, travelled_m: f64, counted_m: f64, velocity_b: &V3) -> V3 {
        let [a_y, a_z] = self.axis_rad;
        V3::new(
            self.scale() * travelled_m - counted_m,
            velocity_b.y - a_y * velocity_b.x,
            velocity_b.z - a_z * velocity_b.x,
        )
    }

    /// Feeds back the odometer block of an estimated error state.
    pub fn correct(&mut self, dx: &ErrorState) {
        self.scale_error -= dx[ODOMETER];
        self.axis_rad[0] -= dx[ODOMETER + 1];
        self.axis_rad[1] -= dx[ODOMETER + 2];
    }
}

/// H of an odometer reading ([`OdometerModel::innovation`]):
/// - the count: (1 + ŝ)·f̂ᵀ·δp + d·δs, with f̂ the machine's forward axis
///   (NED) and d the advance since the origin, `travelled_m` (a distance
///   of metres against a counter of millimetres: no noise of the count
///   multiplies the scale);
/// - across, with the body-velocity error δv_b = Ĉᵀ·δv − Ĉᵀ·[v̂×]·φ:
///   δv_b,y − â_y·δv_b,x − v_x·δa_y, likewise for z.
pub fn odometer_matrix(
    c_bn: &Matrix3<f64>,
    velocity_n: &V3,
    model: &OdometerModel,
    travelled_m: f64,
) -> SMatrix<f64, 3, N> {
    let c_nb = c_bn.transpose();
    let mut body = SMatrix::<f64, 3, N>::zeros();
    body.fixed_view_mut::<3, 3>(0, VEL).copy_from(&c_nb);
    body.fixed_view_mut::<3, 3>(0, ATT)
        .copy_from(&(-c_nb * skew(velocity_n)));
    let forward_mps = (c_nb * velocity_n).x;
    let forward = c_bn.column(0);
    let [a_y, a_z] = model.axis_rad;
    let mut h = SMatrix::<f64, 3, N>::zeros();
    for axis in 0..3 {
        h[(0, POS + axis)] = model.scale() * forward[axis];
    }
    h[(0, ODOMETER)] = travelled_m;
    h.set_row(1, &(body.row(1) - body.row(0) * a_y));
    h.set_row(2, &(body.row(2) - body.row(0) * a_z));
    h[(1, ODOMETER + 1)] = -forward_mps;
    h[(2, ODOMETER + 2)] = -forward_mps;
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise() -> ProcessNoise {
        ProcessNoise {
            accel_vrw: 1e-3,
            gyro_arw: 1e-5,
            accel_bias_rw: 1e-6,
            gyro_bias_rw: 1e-8,
        }
    }

    fn level_dynamics() -> Dynamics {
        Dynamics {
            specific_force_n: V3::new(0.0, 0.0, -9.8),
            c_bn: Matrix3::identity(),
            earth_rate_n: V3::new(6e-5, 0.0, -4e-5),
            transport_rate_n: V3::zeros(),
            gravity_gradient: 3e-6,
        }
    }

    #[test]
    fn tilt_error_couples_into_velocity_with_the_right_sign() {
        // A tilt error φ_N about north on a level platform: Ĉf = f − φ×f
        // reads (0, −g·φ_N, 0) too much east, so δv̇_E = −g·φ_N; likewise
        // δv̇_N = +g·φ_E.
        let f = ErrorStateFilter::system_matrix(&level_dynamics());
        assert!((f[(VEL + 1, ATT)] + 9.8).abs() < 1e-12);
        assert!((f[(VEL, ATT + 1)] - 9.8).abs() < 1e-12);
        assert_eq!(f[(POS, VEL)], 1.0);
        assert_eq!(f[(ATT, GYRO_BIAS)], -1.0);
    }

    #[test]
    fn a_zupt_shrinks_velocity_uncertainty_and_correlated_tilt() {
        let sigma = [
            V3::repeat(0.01),
            V3::repeat(0.1),
            V3::new(1e-3, 1e-3, 1e-2),
            V3::repeat(1e-2),
            V3::repeat(1e-6),
            V3::repeat(1e-3),
        ];
        let mut filter = ErrorStateFilter::new(sigma, noise());
        for _ in 0..100 {
            filter.propagate(&level_dynamics(), 0.1);
        }
        let before = filter.sigma(VEL);
        let tilt_before = filter.sigma(ATT);
        let r = SMatrix::<f64, 3, 3>::identity() * 1e-6;
        let dx = filter
            .update(
                &zupt_matrix(),
                &SVector::<f64, 3>::new(0.05, 0.0, 0.0),
                &r,
                None,
            )
            .unwrap();
        let after = filter.sigma(VEL);
        assert!(after.x < before.x / 10.0 && after.x < 1.1e-3);
        assert!(dx[VEL] > 0.04, "most of the innovation is velocity error");
        // After many more rests the tilt is pinned too.
        for _ in 0..300 {
            filter.propagate(&level_dynamics(), 0.1);
            filter
                .update(&zupt_matrix(), &SVector::<f64, 3>::zeros(), &r, None)
                .unwrap();
        }
        assert!(filter.sigma(ATT).x < tilt_before.x);
        assert!(filter.is_sane());
    }

    #[test]
    fn the_gate_refuses_an_absurd_height() {
        let mut filter = ErrorStateFilter::new([V3::repeat(0.01); 6], noise());
        let r = SMatrix::<f64, 1, 1>::new(1e-4);
        let absurd = SVector::<f64, 1>::new(10.0);
        let err = filter.update(&height_matrix(), &absurd, &r, Some(25.0));
        assert_eq!(err, Err(UpdateError::Gated));
        let fine = SVector::<f64, 1>::new(0.01);
        let dx = filter
            .update(&height_matrix(), &fine, &r, Some(25.0))
            .unwrap();
        // ĥ − h = 0.01 means δp_D = −0.01·(gain).
        assert!(dx[POS + 2] < 0.0);
    }

    #[test]
    fn an_odometer_counting_long_is_taken_for_its_scale_when_the_position_is_known() {
        // Position known to 1 µm after 10 m north on a level body; the
        // odometer counted 10.4 m. With σ_s = 0.05 and R = (1 mm)²: S =
        // 10²·0.0025 + 1e-6 (+1e-12), the scale's gain 10·0.0025 / S, so
        // ŝ = 0.4 × 0.025 / 0.250001.
        let sigma = [
            V3::repeat(1e-6),
            V3::repeat(1e-6),
            V3::repeat(1e-6),
            V3::repeat(1e-6),
            V3::repeat(1e-9),
            V3::new(0.05, 0.0, 0.0),
        ];
        let mut filter = ErrorStateFilter::new(sigma, noise());
        let mut model = OdometerModel::default();
        let velocity_n = V3::zeros();
        let innovation = model.innovation(10.0, 10.4, &velocity_n);
        let h = odometer_matrix(&Matrix3::identity(), &velocity_n, &model, 10.0);
        assert_eq!(h[(0, POS)], 1.0);
        let r = SMatrix::<f64, 3, 3>::identity() * 1e-6;
        // As the filter does it, the scale only considered: it stays.
        let considered = filter.clone().update(&h, &innovation, &r, None).unwrap();
        assert_eq!(considered[ODOMETER], 0.0);
        let dx = filter
            .update_considering(&h, &innovation, &r, None, std::iter::empty())
            .unwrap();
        model.correct(&dx);
        let expected = 0.4 * 0.025 / (0.250001 + 1e-12);
        assert!((model.scale_error - expected).abs() < 1e-9, "{model:?}");
        // The position barely moves: it is known far better than the scale.
        assert!(dx[POS].abs() < 1e-6, "{dx}");
        // σ_s² after: P_s·(R + P_p) / S.
        assert!((filter.p[(ODOMETER, ODOMETER)] - 0.0025 * 1.000001e-6 / 0.250001).abs() < 1e-12);
    }

    #[test]
    fn a_sideways_speed_along_the_odometer_axis_is_taken_for_its_misalignment() {
        // The INS moves at 0.1 m/s forward and 0.001 m/s right (known to
        // 1e-6): an axis 0.01 rad toward y explains it. σ_a = 0.02, R =
        // (1 mm/s)²: the gain on −v_x·δa_y is P_a·v_x / (v_x²·P_a + R) =
        // 4e-5 / 5e-6 = 8, so â_y = 8 × 0.001 = 0.008 (4/5 of the way).
        let sigma = [
            V3::repeat(0.01),
            V3::repeat(1e-6),
            V3::repeat(1e-6),
            V3::repeat(1e-6),
            V3::repeat(1e-9),
            V3::new(0.0, 0.02, 0.02),
        ];
        let mut filter = ErrorStateFilter::new(sigma, noise());
        let mut model = OdometerModel::default();
        let velocity_n = V3::new(0.1, 0.001, 0.0);
        let innovation = model.innovation(0.0, 0.0, &velocity_n);
        let h = odometer_matrix(&Matrix3::identity(), &velocity_n, &model, 0.0);
        let r = SMatrix::<f64, 3, 3>::identity() * 1e-6;
        let dx = filter.update(&h, &innovation, &r, None).unwrap();
        model.correct(&dx);
        assert!((model.axis_rad[0] - 0.008).abs() < 1e-6, "{model:?}");
        assert!(model.axis_rad[1].abs() < 1e-9 && model.scale_error.abs() < 1e-9);
    }
}
