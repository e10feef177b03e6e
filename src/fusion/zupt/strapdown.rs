//! Strapdown mechanisation in a local NED frame with the Earth's rotation
//! and WGS84 normal gravity (Zhang et al. 2024, Sec. 2; docs/papers.md: the
//! paper's simplified model leaves out the Earth rate, which a 0.5 °/h
//! gyro cannot ignore).
//!
//! Position is kept in metres north, east and down of the start point; the
//! latitude and height that gravity, Earth rate and transport rate need are
//! derived from it. Body frame: x forward, y right, z down.

use nalgebra::UnitQuaternion;
use serde::{Deserialize, Serialize};

use crate::fusion::geometry::{V3, earth_rate_n, normal_gravity_mps2, radii_m};

/// Where the mechanisation is anchored: the start point's geodetic
/// latitude and height.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Site {
    pub lat_rad: f64,
    pub height_m: f64,
}

impl Site {
    /// Latitude and height at `position_m` (NED from the start point).
    pub fn at(&self, position_m: &V3) -> (f64, f64) {
        let (meridian, _) = radii_m(self.lat_rad);
        let height = self.height_m - position_m.z;
        (self.lat_rad + position_m.x / (meridian + height), height)
    }

    /// The transport rate ω_en of a velocity at `position_m`, rad/s.
    pub fn transport_rate_n(&self, position_m: &V3, velocity_mps: &V3) -> V3 {
        let (lat, height) = self.at(position_m);
        let (meridian, transverse) = radii_m(lat);
        V3::new(
            velocity_mps.y / (transverse + height),
            -velocity_mps.x / (meridian + height),
            -velocity_mps.y * lat.tan() / (transverse + height),
        )
    }

    /// Normal gravity at `position_m`, m/s², pointing down.
    pub fn gravity_mps2(&self, position_m: &V3) -> f64 {
        let (lat, height) = self.at(position_m);
        normal_gravity_mps2(lat, height)
    }
}

/// The navigation solution the mechanisation integrates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NavState {
    /// North, east, down of the start point, m.
    pub position_m: V3,
    /// North, east, down, m/s.
    pub velocity_mps: V3,
    /// Body to NED.
    pub attitude: UnitQuaternion<f64>,
}

/// One interval's sensor input: mean specific force (m/s²) and angular
/// rate (rad/s) over `dt_s`, bias-compensated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Increment {
    pub accel_mps2: V3,
    pub gyro_rad_per_s: V3,
    pub dt_s: f64,
}

impl NavState {
    /// A state at rest at the start point with the given attitude.
    pub fn at_rest(attitude: UnitQuaternion<f64>) -> NavState {
        NavState {
            position_m: V3::zeros(),
            velocity_mps: V3::zeros(),
            attitude,
        }
    }

    /// Advances the solution over one interval; returns the specific force
    /// resolved in NED (the filter's F matrix needs it).
    ///
    /// Attitude: C_bⁿ(k) = exp(−[ω_inⁿ·dt×])·C_bⁿ(k−1)·exp([ω_ibᵇ·dt×]).
    /// Velocity: v̇ = C_bⁿ f − (2ω_ieⁿ + ω_enⁿ) × v + gⁿ, with C_bⁿ at the
    /// middle of the interval. Position: trapezoidal.
    pub fn advance(&mut self, site: &Site, input: &Increment) -> V3 {
        let dt = input.dt_s;
        let (lat, height) = site.at(&self.position_m);
        let earth = earth_rate_n(lat);
        let transport = site.transport_rate_n(&self.position_m, &self.velocity_mps);
        let nav_rate = earth + transport;
        let half_nav = UnitQuaternion::from_scaled_axis(-nav_rate * (0.5 * dt));
        let half_body = UnitQuaternion::from_scaled_axis(input.gyro_rad_per_s * (0.5 * dt));
        let mid = half_nav * self.attitude * half_body;
        let accel_n = mid * input.accel_mps2;
        let gravity = V3::new(0.0, 0.0, normal_gravity_mps2(lat, height));
        let coriolis = (2.0 * earth + transport).cross(&self.velocity_mps);
        let velocity = self.velocity_mps + (accel_n - coriolis + gravity) * dt;
        self.position_m += (self.velocity_mps + velocity) * (0.5 * dt);
        self.velocity_mps = velocity;
        self.attitude = half_nav * mid * half_body;
        accel_n
    }

    /// Roll, pitch, yaw (rad); yaw in (−π, π].
    pub fn euler(&self) -> (f64, f64, f64) {
        self.attitude.euler_angles()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::geometry::attitude_from_euler;

    /// A perfect IMU at rest reads −g rotated into the body and the Earth
    /// rate rotated into the body: an hour of mechanisation stays put.
    #[test]
    fn perfect_imu_at_rest_stays_put_for_an_hour() {
        let site = Site {
            lat_rad: 31.0_f64.to_radians(),
            height_m: 12.0,
        };
        let attitude = attitude_from_euler(0.02, -0.01, 2.1);
        let gravity = normal_gravity_mps2(site.lat_rad, site.height_m);
        let input = Increment {
            accel_mps2: attitude.inverse() * V3::new(0.0, 0.0, -gravity),
            gyro_rad_per_s: attitude.inverse() * earth_rate_n(site.lat_rad),
            dt_s: 0.01,
        };
        let mut state = NavState::at_rest(attitude);
        for _ in 0..360_000 {
            state.advance(&site, &input);
        }
        assert!(state.position_m.norm() < 1e-3, "{:?}", state.position_m);
        assert!(state.velocity_mps.norm() < 1e-5);
        assert!(state.attitude.angle_to(&attitude) < 1e-9);
    }

    /// Without the Earth-rate terms the same hour drifts: the test above
    /// would catch a mechanisation that ignored them.
    #[test]
    fn ignoring_earth_rate_drifts() {
        let site = Site {
            lat_rad: 31.0_f64.to_radians(),
            height_m: 0.0,
        };
        let attitude = attitude_from_euler(0.0, 0.0, 0.5);
        let gravity = normal_gravity_mps2(site.lat_rad, 0.0);
        let input = Increment {
            accel_mps2: attitude.inverse() * V3::new(0.0, 0.0, -gravity),
            gyro_rad_per_s: V3::zeros(), // as if the gyros did not sense the Earth
            dt_s: 0.01,
        };
        let mut state = NavState::at_rest(attitude);
        for _ in 0..60_000 {
            state.advance(&site, &input);
        }
        assert!(state.position_m.norm() > 10.0, "{:?}", state.position_m);
    }

    #[test]
    fn constant_acceleration_integrates_exactly() {
        let site = Site {
            lat_rad: 0.0,
            height_m: 0.0,
        };
        let attitude = attitude_from_euler(0.0, 0.0, 0.0);
        let gravity = normal_gravity_mps2(0.0, 0.0);
        let mut state = NavState::at_rest(attitude);
        // 0.1 m/s² north for 10 s, gyros reading the Earth rate.
        for _ in 0..1000 {
            state.advance(
                &site,
                &Increment {
                    accel_mps2: V3::new(0.1, 0.0, -gravity),
                    gyro_rad_per_s: earth_rate_n(0.0),
                    dt_s: 0.01,
                },
            );
        }
        assert!(
            (state.position_m.x - 5.0).abs() < 1e-3,
            "{:?}",
            state.position_m
        );
        assert!((state.velocity_mps.x - 1.0).abs() < 1e-4);
    }
}
