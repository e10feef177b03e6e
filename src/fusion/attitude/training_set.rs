//! The ANFIS's training set: the (roll, pitch error) pairs of laser
//! instants (Eq. 16), bounded, stratified by roll and weighted by recency.
//! Each roll bin keeps its newest pairs, so a region visited hours ago is
//! not forgotten because the machine has spent the time elsewhere; a full
//! window forgets the oldest pair of its most populated bin.

use std::collections::VecDeque;
use std::ops::Deref;

use serde::{Deserialize, Serialize};

use super::anfis::AnfisConfig;

/// One training pair from a laser instant (Eq. 16).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TrainingSample {
    /// Laser time, Unix seconds.
    pub t: f64,
    /// Roll at the laser instant (the laser's, β_L).
    pub roll_rad: f64,
    /// Pitch error e_a = α_L − α_I at that instant.
    pub error_rad: f64,
    /// Inclinometer temperature at that instant, if it sends one.
    #[serde(default)]
    pub temp_c: Option<f64>,
    /// Arrival number, assigned by [`TrainingSet::add`]; ages are counted in it.
    #[serde(default)]
    pub seq: u64,
}

/// The pairs, oldest first.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct TrainingSet {
    samples: VecDeque<TrainingSample>,
}

/// What [`TrainingSet::add`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Added {
    /// The index of the pair forgotten to make room, if one was.
    pub removed: Option<usize>,
    /// The roll of the pair added (now the newest).
    pub roll_rad: f64,
}

impl TrainingSet {
    /// An empty set.
    pub fn new() -> TrainingSet {
        TrainingSet::default()
    }

    /// Adds a pair: it replaces the oldest of its roll bin when the bin is
    /// full, else the oldest of the fullest bin when the window is full.
    pub fn add(&mut self, mut sample: TrainingSample, config: &AnfisConfig) -> Added {
        sample.seq = self.samples.back().map_or(0, |s| s.seq + 1);
        let bin_of = |roll_rad: f64| bin(roll_rad, config.bin_width_rad);
        let bin = bin_of(sample.roll_rad);
        let in_bin = self
            .samples
            .iter()
            .filter(|s| bin_of(s.roll_rad) == bin)
            .count();
        let removed = if in_bin >= config.per_bin {
            self.samples.iter().position(|s| bin_of(s.roll_rad) == bin)
        } else if self.samples.len() >= config.window {
            self.oldest_of_fullest_bin(config.bin_width_rad)
        } else {
            None
        };
        if let Some(index) = removed {
            self.samples.remove(index);
        }
        self.samples.push_back(sample);
        Added {
            removed,
            roll_rad: sample.roll_rad,
        }
    }

    /// Where the window is full, the pair to forget: the oldest of the most
    /// populated roll bin, so the rarest regions are the last to go.
    fn oldest_of_fullest_bin(&self, bin_width_rad: f64) -> Option<usize> {
        let mut counts: Vec<(i64, usize)> = Vec::new();
        for s in &self.samples {
            let b = bin(s.roll_rad, bin_width_rad);
            match counts.iter_mut().find(|(c, _)| *c == b) {
                Some((_, n)) => *n += 1,
                None => counts.push((b, 1)),
            }
        }
        let most = counts.iter().map(|&(_, n)| n).max()?;
        self.samples.iter().position(|s| {
            let b = bin(s.roll_rad, bin_width_rad);
            counts.iter().any(|&(c, n)| c == b && n == most)
        })
    }

    /// Recency weights, oldest first: the newest weighs 1, one half-life
    /// older 0.5, never less than the floor.
    pub fn weights(&self, config: &AnfisConfig) -> Vec<f64> {
        let newest = self.samples.back().map_or(0, |s| s.seq);
        self.samples
            .iter()
            .map(|s| {
                let age = (newest - s.seq) as f64;
                (-age / config.half_life).exp2().max(config.min_weight)
            })
            .collect()
    }
}

/// The pairs, read-only.
impl Deref for TrainingSet {
    type Target = VecDeque<TrainingSample>;

    fn deref(&self) -> &VecDeque<TrainingSample> {
        &self.samples
    }
}

/// The roll bin of `roll_rad`.
fn bin(roll_rad: f64, bin_width_rad: f64) -> i64 {
    (roll_rad / bin_width_rad).floor() as i64
}
