//! Small dense linear algebra on fixed-size arrays (n ≤ 6): no allocation, no dependencies.

/// The largest dimension handled.
pub const MAX: usize = 6;

/// A row-major n×n matrix stored in a 6×6 array.
pub type Mat = [f64; MAX * MAX];

/// Solves `a · x = b` for x (n ≤ 6) by Gaussian elimination with partial pivoting, in place:
/// `a` is destroyed and `b` becomes x. Returns `false` when a pivot is smaller than `tiny`
/// relative to the largest entry (numerically singular).
pub fn solve(n: usize, a: &mut Mat, b: &mut [f64; MAX], tiny: f64) -> bool {
    // One elimination per dimension, its loops' bounds known to the compiler (the hexapod's
    // Newton steps solve 6×6 systems every main cycle); the arithmetic is the same in each.
    match n {
        0 => true,
        1 => solve_dim::<1>(a, b, tiny),
        2 => solve_dim::<2>(a, b, tiny),
        3 => solve_dim::<3>(a, b, tiny),
        4 => solve_dim::<4>(a, b, tiny),
        5 => solve_dim::<5>(a, b, tiny),
        6 => solve_dim::<6>(a, b, tiny),
        _ => panic!("linalg::solve: dimension {n} is above {MAX}"),
    }
}

/// [`solve`] for dimension `N`.
#[inline]
fn solve_dim<const N: usize>(a: &mut Mat, b: &mut [f64; MAX], tiny: f64) -> bool {
    let scale = a[..N * MAX]
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    for col in 0..N {
        let mut piv = col;
        for r in col + 1..N {
            if a[r * MAX + col].abs() > a[piv * MAX + col].abs() {
                piv = r;
            }
        }
        if a[piv * MAX + col].abs() <= tiny * scale {
            return false;
        }
        if piv != col {
            for c in 0..N {
                a.swap(piv * MAX + c, col * MAX + c);
            }
            b.swap(piv, col);
        }
        for r in col + 1..N {
            let f = a[r * MAX + col] / a[col * MAX + col];
            if f != 0.0 {
                for c in col..N {
                    a[r * MAX + c] -= f * a[col * MAX + c];
                }
                b[r] -= f * b[col];
            }
        }
    }
    for col in (0..N).rev() {
        let mut s = b[col];
        for c in col + 1..N {
            s -= a[col * MAX + c] * b[c];
        }
        b[col] = s / a[col * MAX + col];
    }
    true
}

/// Inverts the n×n matrix `a` into `out`. Returns `false` if it is numerically singular.
pub fn invert(n: usize, a: &Mat, out: &mut Mat, tiny: f64) -> bool {
    for col in 0..n {
        let mut m = *a;
        let mut e = [0.0; MAX];
        e[col] = 1.0;
        if !solve(n, &mut m, &mut e, tiny) {
            return false;
        }
        for r in 0..n {
            out[r * MAX + col] = e[r];
        }
    }
    true
}

/// The singular values of the n×n matrix `a`, largest first (square roots of the eigenvalues of
/// aᵀa, found by cyclic Jacobi rotations).
pub fn singular_values(n: usize, a: &Mat) -> [f64; MAX] {
    let mut s: Mat = [0.0; MAX * MAX];
    for i in 0..n {
        for j in 0..n {
            s[i * MAX + j] = (0..n).map(|k| a[k * MAX + i] * a[k * MAX + j]).sum();
        }
    }
    for _sweep in 0..60 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| s[i * MAX + j].powi(2))
            .sum();
        let diag: f64 = (0..n).map(|i| s[i * MAX + i].powi(2)).sum();
        if off <= 1e-30 * diag.max(f64::MIN_POSITIVE) {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = s[p * MAX + q];
                if apq.abs() < 1e-300 {
                    continue;
                }
                let theta = (s[q * MAX + q] - s[p * MAX + p]) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let sn = t * c;
                for k in 0..n {
                    let skp = s[k * MAX + p];
                    let skq = s[k * MAX + q];
                    s[k * MAX + p] = c * skp - sn * skq;
                    s[k * MAX + q] = sn * skp + c * skq;
                }
                for k in 0..n {
                    let spk = s[p * MAX + k];
                    let sqk = s[q * MAX + k];
                    s[p * MAX + k] = c * spk - sn * sqk;
                    s[q * MAX + k] = sn * spk + c * sqk;
                }
            }
        }
    }
    let mut out = [0.0; MAX];
    for i in 0..n {
        out[i] = s[i * MAX + i].max(0.0).sqrt();
    }
    out[..n].sort_by(|x, y| y.total_cmp(x));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_and_inverts_a_3x3() {
        let mut a: Mat = [0.0; 36];
        let rows = [[2.0, 1.0, -1.0], [-3.0, -1.0, 2.0], [-2.0, 1.0, 2.0]];
        for (i, r) in rows.iter().enumerate() {
            a[i * MAX..i * MAX + 3].copy_from_slice(r);
        }
        let mut b = [8.0, -11.0, -3.0, 0.0, 0.0, 0.0];
        let mut m = a;
        assert!(solve(3, &mut m, &mut b, 1e-12));
        for (got, want) in b.iter().zip([2.0, 3.0, -1.0]) {
            assert!((got - want).abs() < 1e-12);
        }
        let mut inv = [0.0; 36];
        assert!(invert(3, &a, &mut inv, 1e-12));
        for i in 0..3 {
            for j in 0..3 {
                let p: f64 = (0..3).map(|k| a[i * MAX + k] * inv[k * MAX + j]).sum();
                assert!((p - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn singular_matrices_are_detected_and_have_a_zero_singular_value() {
        let mut a: Mat = [0.0; 36];
        a[0] = 1.0;
        a[1] = 2.0;
        a[MAX] = 2.0;
        a[MAX + 1] = 4.0;
        let mut inv = [0.0; 36];
        assert!(!invert(2, &a, &mut inv, 1e-12));
        let s = singular_values(2, &a);
        assert!((s[0] - 5.0).abs() < 1e-12 && s[1].abs() < 1e-7, "{s:?}");
    }

    #[test]
    fn singular_values_of_a_diagonal_matrix() {
        let mut a: Mat = [0.0; 36];
        for (i, v) in [3.0, -7.0, 0.5, 2.0, 1.0, 4.0].iter().enumerate() {
            a[i * MAX + i] = *v;
        }
        let s = singular_values(6, &a);
        assert_eq!(s, [7.0, 4.0, 3.0, 2.0, 1.0, 0.5]);
    }
}
