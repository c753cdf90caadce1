//! HIP's cost combination (section II-III): a geometric costmap is rescaled
//! so its values sit in the range of the learned cost, `C_costmap(x) = alpha *
//! exp C'(x) / sum_x' exp C'(x')` (alpha = eta / H = 6.4 with the paper's
//! eta = 64 and H = 10), and combined with a learned cost as
//! `(1 - phi) C_learned + phi C_costmap` (phi = 0.75).
//!
//! Lethal cells (infinite cost) stay lethal and are left out of the softmax;
//! NaN cells (unknown) also stay NaN. The planner that uses these (and its
//! phi, alpha) is `farsight_subgoal_selection::hip`.

/// The paper's rescaling of a geometric costmap (a softmax over the finite
/// cells, times alpha).
pub fn hip_scaled_costmap(costs: &[f32], alpha: f64) -> Vec<f32> {
    let max = costs
        .iter()
        .copied()
        .filter(|c| c.is_finite())
        .fold(f32::NEG_INFINITY, f32::max);
    // Subtracting the maximum keeps exp finite; the ratio is unchanged.
    let sum: f64 = costs
        .iter()
        .filter(|c| c.is_finite())
        .map(|&c| ((c - max) as f64).exp())
        .sum();
    costs
        .iter()
        .map(|&c| {
            if c.is_finite() {
                (alpha * ((c - max) as f64).exp() / sum) as f32
            } else {
                c
            }
        })
        .collect()
}

/// `(1 - phi) learned + phi geometric`, per cell or per trajectory.
pub fn hip_combined(learned: f64, geometric: f64, phi: f64) -> f64 {
    (1.0 - phi) * learned + phi * geometric
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaled_costmap_by_hand() {
        // exp(0), exp(ln 3) over a sum of 1 + 3 = 4, times alpha 6.4: 1.6 and 4.8.
        let s = hip_scaled_costmap(&[0.0, 3f32.ln(), f32::INFINITY, f32::NAN], 6.4);
        assert!(
            (s[0] - 1.6).abs() < 1e-5 && (s[1] - 4.8).abs() < 1e-5,
            "{s:?}"
        );
        assert!(s[2].is_infinite() && s[3].is_nan());
        // The maximum of the scaled map never exceeds alpha.
        let big = hip_scaled_costmap(&[100.0, 90.0, 1.0], 6.4);
        assert!(big.iter().all(|&c| c <= 6.4 + 1e-6) && big[0] > big[1]);
    }

    #[test]
    fn phi_weights_the_terms() {
        assert_eq!(hip_combined(4.0, 8.0, 0.75), 7.0);
        assert_eq!(hip_combined(4.0, 8.0, 0.0), 4.0);
        assert_eq!(hip_combined(4.0, 8.0, 1.0), 8.0);
    }
}
