//! `boundcovar` (Algorithm 1, line 24): clip the eigenvalues of a covariance matrix to
//! [λ_min, λ_max] and rebuild it. The eigenvalues are bounded, not the diagonal: clamping the
//! diagonal leaves the largest eigenvalue unbounded and can make Σ indefinite.

use nalgebra::DMatrix;

use crate::error::ParameterError;

/// Bounds on the eigenvalues of Σ. `max = f64::INFINITY` means no upper bound.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EigenvalueBounds {
    /// Lower bound λ_min, ≥ 0: keeps exploring in every direction (0: no lower bound).
    pub min: f64,
    /// Upper bound λ_max, ≥ `min`; `f64::INFINITY` for none.
    pub max: f64,
}

impl EigenvalueBounds {
    /// Bounds [min, max]; refuses a negative or non-finite `min` and a `max` below it or NaN.
    pub fn new(min: f64, max: f64) -> Result<Self, ParameterError> {
        if !(min.is_finite() && min >= 0.0) {
            return Err(ParameterError::OutOfRange {
                field: "lambda_min",
                value: min.to_string(),
                reason: "must be finite and >= 0",
            });
        }
        if max.is_nan() || max < min {
            return Err(ParameterError::OutOfRange {
                field: "lambda_max",
                value: max.to_string(),
                reason: "must be >= lambda_min",
            });
        }
        Ok(Self { min, max })
    }

    /// [0, ∞): `boundcovar` changes nothing (CEM as usually written).
    pub fn unbounded() -> Self {
        Self {
            min: 0.0,
            max: f64::INFINITY,
        }
    }

    /// `v` clipped to [min, max].
    #[inline]
    pub fn clip(&self, v: f64) -> f64 {
        v.max(self.min).min(self.max)
    }
}

/// Eigenvalues (ascending order not guaranteed) and eigenvectors (columns) of a symmetric matrix.
///
/// Not nalgebra's `SymmetricEigen`: it sometimes pairs eigenvalues with the wrong eigenvectors
/// (nalgebra issue #1109, open in 0.33), and V·clip(Λ)·Vᵀ then is a different matrix. A P = 5
/// per-time-step run had Σ wrong by 4·10⁻⁶ relative in one update, found by an independent
/// NumPy re-implementation of the update. The crate's tred2/tql2 reconstructs to rounding.
pub fn symmetric_eigen(m: &DMatrix<f64>) -> (Vec<f64>, DMatrix<f64>) {
    let n = m.nrows();
    if n == 2 {
        let (l, v) = eigen2(m[(0, 0)], m[(0, 1)], m[(1, 1)]);
        return (
            l.to_vec(),
            DMatrix::from_column_slice(2, 2, &[v[0][0], v[0][1], v[1][0], v[1][1]]),
        );
    }
    let mut vectors = m.clone();
    let (mut values, mut scratch) = (vec![0.0; n], vec![0.0; n]);
    crate::symeig::symmetric_eigen(n, vectors.as_mut_slice(), &mut values, &mut scratch);
    (values, vectors)
}

/// The largest eigenvalue of the symmetric matrix `m` (λ of a covariance); 0 for 0×0.
pub fn largest_eigenvalue(m: &DMatrix<f64>) -> f64 {
    match m.nrows() {
        0 => 0.0,
        1 => m[(0, 0)],
        2 => {
            let (l, _) = eigen2(m[(0, 0)], m[(0, 1)], m[(1, 1)]);
            l[0].max(l[1])
        }
        // Eigenvalues only, by the crate's QL (`symmetric_eigen`'s bits without its
        // eigenvectors): nalgebra's `symmetric_eigenvalues` took 11.1 µs at P = 21 (T-ball)
        // against 7.9, and was a sixth of the pipeline recorder's profile there.
        n => {
            let mut v = m.as_slice().to_vec();
            let mut scratch = vec![0.0; 3 * n];
            crate::symeig::largest_eigenvalue(n, &mut v, &mut scratch)
        }
    }
}

/// Closed-form eigen-decomposition of the symmetric 2×2 matrix [[a, b], [b, c]]:
/// returns the eigenvalues and unit eigenvectors (as [x, y] pairs).
#[inline]
pub fn eigen2(a: f64, b: f64, c: f64) -> ([f64; 2], [[f64; 2]; 2]) {
    // Entries past ~1e154 overflow the squares below (λ came out ∞ for a finite Σ), entries
    // below ~1e-154 underflow them (λ of a collapsed CEM Σ came out wrong): such a matrix is
    // decomposed scaled by a power of 2, which is exact.
    if let Some(unscale) = crate::symeig::unscale_for(a.abs().max(b.abs()).max(c.abs())) {
        let (l, v) = eigen2(a / unscale, b / unscale, c / unscale);
        return ([l[0] * unscale, l[1] * unscale], v);
    }
    let half_trace = 0.5 * (a + c);
    let half_diff = 0.5 * (a - c);
    // sqrt(x² + y²) rather than hypot: covariance entries are far from overflow, and hypot's
    // extra care costs more than the rest of the 2×2 update.
    let r = (half_diff * half_diff + b * b).sqrt();
    let l1 = half_trace + r;
    // When l2 ≪ l1 this subtraction cancels, but its absolute error, a few ulps of l1, is what
    // rounding a, b and c to f64 already does to l2 (Weyl: |Δl| ≤ ‖ΔΣ‖ ≈ ε·l1), so det/l1
    // would be no more accurate in the matrix's own terms; and below λ_min the clip replaces it.
    let l2 = half_trace - r;
    if b == 0.0 {
        // Already diagonal: keep the axes so that clipping leaves a diagonal matrix diagonal.
        return ([a, c], [[1.0, 0.0], [0.0, 1.0]]);
    }
    // Eigenvector of l1: (b, l1 − a), normalised; the other is orthogonal to it.
    let (x, y) = if half_diff >= 0.0 {
        (l1 - c, b)
    } else {
        (b, l1 - a)
    };
    let n = (x * x + y * y).sqrt();
    let (x, y) = (x / n, y / n);
    ([l1, l2], [[x, y], [-y, x]])
}

/// boundcovar for a symmetric 2×2 matrix given as (a, b, c); returns the bounded (a, b, c).
#[inline]
pub fn boundcovar2(a: f64, b: f64, c: f64, bounds: EigenvalueBounds) -> (f64, f64, f64) {
    let (l, v) = eigen2(a, b, c);
    let (l0, l1) = (bounds.clip(l[0]), bounds.clip(l[1]));
    if l0 == l[0] && l1 == l[1] {
        return (a, b, c);
    }
    let ([x0, y0], [x1, y1]) = (v[0], v[1]);
    (
        l0 * x0 * x0 + l1 * x1 * x1,
        l0 * x0 * y0 + l1 * x1 * y1,
        l0 * y0 * y0 + l1 * y1 * y1,
    )
}

/// boundcovar for a symmetric 2×2 matrix without branches on the eigenvectors, so a loop over
/// many matrices vectorises: with eigenvalues l1 ≥ l2, any matrix function satisfies
/// f(Σ) = f(l2)·I + (f(l1) − f(l2))/(l1 − l2)·(Σ − l2·I) (Lagrange interpolation; exact for
/// 2×2), and f = clip to [λ_min, λ_max]. When l1 = l2, Σ − l2·I = 0 and the slope is irrelevant.
#[inline(always)]
pub fn boundcovar2_interpolated(
    a: f64,
    b: f64,
    c: f64,
    bounds: EigenvalueBounds,
) -> (f64, f64, f64) {
    let half_diff = 0.5 * (a - c);
    let r = (half_diff * half_diff + b * b).sqrt();
    let mid = 0.5 * (a + c);
    let (l1, l2) = (mid + r, mid - r);
    let (f1, f2) = (bounds.clip(l1), bounds.clip(l2));
    let spread = (l1 - l2).max(f64::MIN_POSITIVE);
    let slope = (f1 - f2) / spread;
    (f2 + slope * (a - l2), slope * b, f2 + slope * (c - l2))
}

/// boundcovar for a symmetric matrix of any size: V·clip(Λ)·Vᵀ, symmetrised exactly.
pub fn boundcovar(m: &DMatrix<f64>, bounds: EigenvalueBounds) -> DMatrix<f64> {
    let n = m.nrows();
    if n == 2 {
        let (a, b, c) = boundcovar2(m[(0, 0)], m[(0, 1)], m[(1, 1)], bounds);
        return DMatrix::from_row_slice(2, 2, &[a, b, b, c]);
    }
    let (values, vectors) = symmetric_eigen(m);
    let mut scaled = vectors.clone();
    for (j, v) in values.iter().enumerate() {
        scaled.column_mut(j).scale_mut(bounds.clip(*v));
    }
    let out = scaled * vectors.transpose();
    // Rounding leaves V·Λ·Vᵀ asymmetric in the last bits; Σ must be exactly symmetric.
    (&out + out.transpose()) * 0.5
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_symmetric(rng: &mut impl Rng, n: usize) -> DMatrix<f64> {
        let a = DMatrix::from_fn(n, n, |_, _| rng.random_range(-10.0..10.0));
        // Mix of PSD (AᵀA) and indefinite inputs.
        if rng.random_bool(0.5) {
            a.transpose() * &a
        } else {
            (&a + a.transpose()) * 0.5
        }
    }

    #[test]
    fn property_symmetric_psd_and_within_bounds() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for trial in 0..500 {
            let n = 1 + trial % 6;
            let m = random_symmetric(&mut rng, n);
            let min = rng.random_range(0.0..5.0);
            let max = if rng.random_bool(0.3) {
                f64::INFINITY
            } else {
                min + rng.random_range(0.0..50.0)
            };
            let bounds = EigenvalueBounds::new(min, max).unwrap();
            let b = boundcovar(&m, bounds);
            assert_eq!(b, b.transpose(), "not symmetric: {b}");
            let e = b.clone().symmetric_eigen();
            let tol = 1e-9 * (1.0 + m.amax());
            for l in e.eigenvalues.iter() {
                assert!(*l >= -tol, "not PSD: {l}");
                assert!(
                    *l >= min - tol && *l <= max + tol,
                    "{l} outside [{min}, {max}]"
                );
            }
        }
    }

    /// V·Λ·Vᵀ of `symmetric_eigen` is the matrix, to rounding.
    fn reconstruction_error(m: &DMatrix<f64>) -> f64 {
        let (values, vectors) = symmetric_eigen(m);
        let r = &vectors * DMatrix::from_diagonal(&values.into()) * vectors.transpose();
        (r - m).amax() / m.amax()
    }

    #[test]
    fn eigenvectors_pair_with_their_eigenvalues() {
        // Step 0 of update 11 of a P = 5 per-time-step run, and nalgebra issue #1109's 4×4:
        // nalgebra's SymmetricEigen reconstructs them only to 1.6·10⁻³ and 3.4 (relative).
        #[rustfmt::skip]
        let p5 = DMatrix::from_row_slice(5, 5, &[
            2754.238353652292, 2252.365923053509, 391.5453845549052, -186.3675409692941, -544.8932881167427,
            2252.365923053509, 2760.5640186642595, 262.78576499123983, -1173.4888601296846, -1132.7861660549054,
            391.5453845549052, 262.78576499123983, 62.845951188101985, 39.74371399645879, -36.68934727743975,
            -186.3675409692941, -1173.4888601296846, 39.74371399645879, 1166.0842787578658, 804.5473845337098,
            -544.8932881167427, -1132.7861660549054, -36.68934727743975, 804.5473845337098, 625.3656580593903,
        ]);
        #[rustfmt::skip]
        let issue = DMatrix::from_row_slice(4, 4, &[
            -19884.07, -10.07188, 11.277279, -188560.63,
            -10.07188, 12.518197, 1.3770627, -102.97504,
            11.277279, 1.3770627, 14.587362, 113.26099,
            -188560.63, -102.97504, 113.26099, -1788112.3,
        ]);
        for m in [&p5, &issue] {
            let err = reconstruction_error(m);
            assert!(err < 1e-13, "relative error {err:e} for {m}");
        }
        // Clipping only the small eigenvalues leaves the large directions as they were.
        let b = boundcovar(&p5, EigenvalueBounds::new(2.0, f64::INFINITY).unwrap());
        let mut l = symmetric_eigen(&b).0;
        l.sort_by(f64::total_cmp);
        let mut l0 = symmetric_eigen(&p5).0;
        l0.sort_by(f64::total_cmp);
        for (a, b) in l.iter().zip(&l0) {
            assert!((a - b.max(2.0)).abs() < 1e-9 * l0[4], "{l:?} from {l0:?}");
        }
    }

    #[test]
    fn reconstructs_random_symmetric_matrices() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for trial in 0..2000 {
            let m = random_symmetric(&mut rng, 3 + trial % 20);
            let err = reconstruction_error(&m);
            assert!(err < 1e-12, "relative error {err:e} for {m}");
        }
    }

    #[test]
    fn interpolated_2x2_matches_eigen_clipping() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for _ in 0..2000 {
            let m = random_symmetric(&mut rng, 2);
            let min = rng.random_range(0.0..5.0);
            let bounds = EigenvalueBounds::new(min, min + rng.random_range(0.0..50.0)).unwrap();
            let (a, b, c) = boundcovar2_interpolated(m[(0, 0)], m[(0, 1)], m[(1, 1)], bounds);
            let (ea, eb, ec) = boundcovar2(m[(0, 0)], m[(0, 1)], m[(1, 1)], bounds);
            let tol = 1e-12 * (1.0 + m.amax());
            assert!((a - ea).abs() < tol && (b - eb).abs() < tol && (c - ec).abs() < tol);
        }
        let (a, b, c) =
            boundcovar2_interpolated(3.0, 0.0, 3.0, EigenvalueBounds::new(4.0, 5.0).unwrap());
        assert_eq!((a, b, c), (4.0, 0.0, 4.0));
    }

    #[test]
    fn matrix_within_bounds_is_unchanged() {
        let m = DMatrix::from_row_slice(2, 2, &[3.0, 1.0, 1.0, 3.0]);
        assert_eq!(boundcovar(&m, EigenvalueBounds::new(1.0, 5.0).unwrap()), m);
    }

    #[test]
    fn bounds_eigenvalues_not_the_diagonal() {
        // Diagonal 1, eigenvalues 1.9 and 0.1: a diagonal clamp to [0.5, 1.5] would change
        // nothing, the eigenvalue bound must.
        let m = DMatrix::from_row_slice(2, 2, &[1.0, 0.9, 0.9, 1.0]);
        let b = boundcovar(&m, EigenvalueBounds::new(0.5, 1.5).unwrap());
        let mut l = symmetric_eigen(&b).0;
        l.sort_by(f64::total_cmp);
        assert!(
            (l[0] - 0.5).abs() < 1e-12 && (l[1] - 1.5).abs() < 1e-12,
            "{l:?}"
        );
        let b3 = boundcovar(
            &DMatrix::from_row_slice(3, 3, &[1.0, 0.9, 0.0, 0.9, 1.0, 0.0, 0.0, 0.0, 1.0]),
            EigenvalueBounds::new(0.5, 1.5).unwrap(),
        );
        assert!((largest_eigenvalue(&b3) - 1.5).abs() < 1e-12);
    }

    #[test]
    fn eigen2_matches_general_solver() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for _ in 0..200 {
            let (a, b, c) = (
                rng.random_range(-5.0..5.0),
                rng.random_range(-5.0..5.0),
                rng.random_range(-5.0..5.0),
            );
            let (l, v) = eigen2(a, b, c);
            let m = nalgebra::Matrix2::new(a, b, b, c);
            for i in 0..2 {
                let x = nalgebra::Vector2::new(v[i][0], v[i][1]);
                assert!((m * x - x * l[i]).amax() < 1e-9);
                assert!((x.norm() - 1.0).abs() < 1e-12);
            }
        }
    }

    /// The closed form squares the entries: a 2×2 Σ of entries 1e170 had λ = ∞ (the summary of
    /// an update from λ_init = 1e300 reported it), [[2, 1], [1, 1.5]]·1e-170 (a collapsed CEM
    /// Σ) had λ = 1.75e-170 instead of 2.78e-170. The eigenpairs of a scaled matrix must be
    /// those of the unscaled one, scaled.
    #[test]
    fn eigen2_of_entries_far_from_one() {
        let (l, v) = eigen2(2.0, 1.0, 1.5);
        for scale in [1e-300, 1e-170, 1e170, 1e300] {
            let (ls, vs) = eigen2(2.0 * scale, scale, 1.5 * scale);
            for i in 0..2 {
                assert!(
                    (ls[i] / scale - l[i]).abs() < 1e-14 * l[i].abs(),
                    "scale {scale:e}: {ls:?} vs {l:?}"
                );
                for j in 0..2 {
                    assert!((vs[i][j] - v[i][j]).abs() < 1e-14, "{vs:?} vs {v:?}");
                }
            }
            let m = DMatrix::from_row_slice(2, 2, &[2.0 * scale, scale, scale, 1.5 * scale]);
            let lambda = largest_eigenvalue(&m) / scale;
            assert!((lambda - l[0].max(l[1])).abs() < 1e-14 * lambda, "{lambda}");
        }
    }

    #[test]
    fn rejects_inverted_bounds() {
        assert!(EigenvalueBounds::new(2.0, 1.0).is_err());
        assert!(EigenvalueBounds::new(-1.0, 1.0).is_err());
        assert!(EigenvalueBounds::new(f64::NAN, 1.0).is_err());
    }
}
