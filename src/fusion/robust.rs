//! Robust spreads learnt from the data (issue 54's monitors): a median
//! shrugs off the spikes it is there to find.

/// σ of a Gaussian per median absolute value (or absolute deviation).
pub const MAD_TO_SIGMA: f64 = 1.4826;

/// The median of `values` (for an even count the upper of the middle
/// two), reordering them in place; `values` must not be empty.
pub fn median_in_place(values: &mut [f64]) -> f64 {
    let middle = values.len() / 2;
    *values.select_nth_unstable_by(middle, f64::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_median_is_the_middle_value_and_the_upper_of_two() {
        assert_eq!(median_in_place(&mut [3.0, -1.0, 2.0]), 2.0);
        assert_eq!(median_in_place(&mut [4.0, 1.0, 3.0, 2.0]), 3.0);
        assert_eq!(median_in_place(&mut [7.0]), 7.0);
    }
}
