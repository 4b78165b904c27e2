//! Non-negative least squares (Lawson and Hanson's active-set method) in the two shapes the
//! estimate needs: on small normal equations (the analytic and hybrid models' weights), and on
//! a wide matrix with few rows, which solves a least-distance problem (the basis model's
//! solve kept non-negative in every cell of its BRDF, `least_distance`).
//!
//! The method adds one variable at a time to a passive (free) set and solves the
//! unconstrained problem on that set; a passive variable that would go negative is stepped
//! back to zero and dropped. Solutions keep few variables, so each step solves a small system.

use nalgebra::{DMatrix, DVector};

/// The problem as Lawson–Hanson sees it: minimise ½cᵀGc − bᵀc over c ≥ 0, with G = XᵀX and
/// b = Xᵀy. Implemented for G given ([`Gram`]) and for X given ([`Columns`]), where G would be
/// too large to form.
trait NormalEquations {
    /// The variables' count.
    fn len(&self) -> usize;
    /// Outer steps at most (each frees one variable; a guard, not reached in practice).
    fn max_steps(&self) -> usize;
    /// bⱼ, for the tolerance on the gradient.
    fn b(&self, j: usize) -> f64;
    /// b − G·c, the negative gradient.
    fn gradient(&self, c: &DVector<f64>) -> DVector<f64>;
    /// The unconstrained minimiser over the variables `idx` (the others zero), in that order.
    fn solve_restricted(&self, idx: &[usize]) -> DVector<f64>;
}

struct Gram<'a> {
    g: &'a DMatrix<f64>,
    b: &'a DVector<f64>,
}

impl NormalEquations for Gram<'_> {
    fn len(&self) -> usize {
        self.b.len()
    }
    fn max_steps(&self) -> usize {
        4 * self.b.len() + 8
    }
    fn b(&self, j: usize) -> f64 {
        self.b[j]
    }
    fn gradient(&self, c: &DVector<f64>) -> DVector<f64> {
        self.b - self.g * c
    }
    fn solve_restricted(&self, idx: &[usize]) -> DVector<f64> {
        let n = idx.len();
        let mut sub = DMatrix::from_fn(n, n, |i, j| self.g[(idx[i], idx[j])]);
        let rhs = DVector::from_fn(n, |i, _| self.b[idx[i]]);
        // A negligible ridge keeps the Cholesky defined for a column that sees no light.
        let tiny = 1e-13 * (0..n).map(|i| sub[(i, i)]).fold(0.0, f64::max);
        (0..n).for_each(|i| sub[(i, i)] += tiny.max(f64::MIN_POSITIVE));
        sub.cholesky()
            .map(|ch| ch.solve(&rhs))
            .unwrap_or_else(|| DVector::zeros(n))
    }
}

/// X (few rows, many columns) and y, with b = Xᵀy precomputed.
struct Columns<'a> {
    x: &'a DMatrix<f64>,
    y: &'a DVector<f64>,
    b: DVector<f64>,
}

impl NormalEquations for Columns<'_> {
    fn len(&self) -> usize {
        self.x.ncols()
    }
    fn max_steps(&self) -> usize {
        // The passive set stays within X's few rows, but variables come and go many times
        // over a wide X: SciPy's bound, three steps per variable.
        3 * self.x.ncols() + 8
    }
    fn b(&self, j: usize) -> f64 {
        self.b[j]
    }
    fn gradient(&self, c: &DVector<f64>) -> DVector<f64> {
        self.x.tr_mul(&(self.y - self.x * c))
    }
    fn solve_restricted(&self, idx: &[usize]) -> DVector<f64> {
        // By SVD of the columns themselves, not their normal equations: the least-distance
        // problems this serves are badly scaled, and squaring the condition number would cost
        // the feasibility of its answer.
        let sub = self.x.select_columns(idx);
        let svd = sub.svd(true, true);
        let eps = 1e-15 * svd.singular_values.max();
        svd.solve(self.y, eps)
            .unwrap_or_else(|_| DVector::zeros(idx.len()))
    }
}

/// Non-negative least squares on the normal equations: minimises ‖Xc − y‖² subject to c ≥ 0,
/// given G = XᵀX and b = Xᵀy. Small systems only (a dozen unknowns for the analytic model,
/// about a hundred for the hybrid model's mix); returns c.
pub(crate) fn nnls(g: &DMatrix<f64>, b: &DVector<f64>) -> DVector<f64> {
    lawson_hanson(&Gram { g, b })
}

fn lawson_hanson(p: &impl NormalEquations) -> DVector<f64> {
    let m = p.len();
    let mut c = DVector::zeros(m);
    let mut passive = vec![false; m];
    // A variable that was freed and at once fixed again (its unconstrained value not
    // positive, by rounding) is not tried again until another one is freed for good; without
    // this, it would be picked again and again until the step bound.
    let mut skip = vec![false; m];
    // Each outer step frees one variable, each inner step fixes at least one.
    for _ in 0..p.max_steps() {
        let grad = p.gradient(&c);
        let next = (0..m)
            .filter(|&j| !passive[j] && !skip[j] && grad[j] > 1e-12 * (1.0 + p.b(j).abs()))
            .max_by(|&i, &j| grad[i].total_cmp(&grad[j]));
        let Some(j) = next else { break };
        passive[j] = true;
        loop {
            let z = solve_passive(p, &passive);
            if (0..m).all(|k| !passive[k] || z[k] > 0.0) {
                c = z;
                break;
            }
            // Step from c towards z until the first passive variable reaches zero.
            let mut step = 1.0f64;
            for k in 0..m {
                if passive[k] && z[k] <= 0.0 {
                    step = step.min(c[k] / (c[k] - z[k]).max(f64::MIN_POSITIVE));
                }
            }
            c = &c + (&z - &c) * step;
            for k in 0..m {
                if passive[k] && c[k] <= 1e-15 {
                    passive[k] = false;
                    c[k] = 0.0;
                }
            }
            if !passive.iter().any(|p| *p) {
                break;
            }
        }
        if passive[j] {
            skip.iter_mut().for_each(|s| *s = false);
        } else {
            skip[j] = true;
        }
    }
    c
}

/// The unconstrained solution over the passive variables (the others zero).
fn solve_passive(p: &impl NormalEquations, passive: &[bool]) -> DVector<f64> {
    let idx: Vec<usize> = (0..passive.len()).filter(|&k| passive[k]).collect();
    let z = p.solve_restricted(&idx);
    let mut out = DVector::zeros(passive.len());
    for (i, &k) in idx.iter().enumerate() {
        out[k] = z[i];
    }
    out
}

/// Least distance: the shortest z with E·z ≥ f, row by row (E has few columns and any number
/// of rows); `None` if no z satisfies every row.
///
/// Lawson and Hanson's reduction to NNLS (Solving Least Squares Problems, ch. 23): with
/// u ≥ 0 minimising ‖[Eᵀ; fᵀ]·u − (0, …, 0, 1)‖ and r that residual, z = −r₁..ₙ / rₙ₊₁. Its
/// passive set holds at most n + 1 rows, so the cost is a few passes over E whatever its
/// length.
pub(crate) fn least_distance(e: &DMatrix<f64>, f: &DVector<f64>) -> Option<DVector<f64>> {
    let n = e.ncols();
    // z = 0 when every bound is at most zero; otherwise the bounds are scaled to at most 1, so
    // that the reduction's tolerances are relative (z scales with them).
    let scale = f.max();
    if scale <= 0.0 {
        return Some(DVector::zeros(n));
    }
    let mut x = DMatrix::zeros(n + 1, e.nrows());
    x.view_mut((0, 0), (n, e.nrows())).copy_from(&e.transpose());
    x.row_mut(n).copy_from(&(f / scale).transpose());
    let mut y = DVector::zeros(n + 1);
    y[n] = 1.0;
    let b = x.tr_mul(&y);
    let u = lawson_hanson(&Columns { x: &x, y: &y, b });
    let r = &x * u - y;
    // At the answer rₙ₊₁ = −1 / (1 + ‖z‖²); a residual of (almost) zero means the rows cannot
    // all hold.
    if r.norm() <= 1e-12 || r[n].abs() <= 1e-12 {
        return None;
    }
    Some(DVector::from_fn(n, |i, _| -r[i] / r[n] * scale))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn nnls_matches_enumeration_of_active_sets() {
        // Against the brute-force answer: every subset of free variables, solved and checked.
        // Tolerance 1e-9 relative: both are f64 Cholesky solves of the same small systems.
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        for _ in 0..200 {
            let (rows, m) = (12, 4);
            let x = DMatrix::from_fn(rows, m, |_, _| rng.random_range(-1.0..1.0));
            let y = DVector::from_fn(rows, |_, _| rng.random_range(-1.0..1.0));
            let g = x.transpose() * &x;
            let b = x.transpose() * &y;
            let c = nnls(&g, &b);
            let cost = |c: &DVector<f64>| (&x * c - &y).norm_squared();
            let mut best = f64::INFINITY;
            for mask in 0..(1u32 << m) {
                let passive: Vec<bool> = (0..m).map(|k| mask & (1 << k) != 0).collect();
                let z = solve_passive(&Gram { g: &g, b: &b }, &passive);
                if z.iter().all(|v| *v >= 0.0) {
                    best = best.min(cost(&z));
                }
            }
            assert!(c.iter().all(|v| *v >= 0.0));
            assert!(
                cost(&c) <= best * (1.0 + 1e-9) + 1e-12,
                "{} > {best}",
                cost(&c)
            );
        }
    }

    #[test]
    fn least_distance_finds_the_nearest_point_of_a_polytope() {
        // Two variables, many half-planes: the answer must satisfy every row, and no feasible
        // point of a fine grid may be nearer the origin.
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        for _ in 0..50 {
            let rows = 40;
            let e = DMatrix::from_fn(rows, 2, |_, _| rng.random_range(-1.0..1.0));
            // Feasible by construction: every row holds at a random point, with slack.
            let p = DVector::from_fn(2, |_, _| rng.random_range(-2.0..2.0));
            let f = DVector::from_fn(rows, |i, _| (e.row(i) * &p)[0] - rng.random_range(0.0..0.5));
            let z = least_distance(&e, &f).expect("feasible");
            let slack = &e * &z - &f;
            assert!(slack.min() >= -1e-9, "violated by {}", -slack.min());
            let steps = 400;
            for i in 0..=steps {
                for j in 0..=steps {
                    let q = DVector::from_vec(vec![
                        -3.0 + 6.0 * i as f64 / steps as f64,
                        -3.0 + 6.0 * j as f64 / steps as f64,
                    ]);
                    if (&e * &q - &f).min() >= 0.0 {
                        assert!(q.norm() >= z.norm() - 1e-9, "{} < {}", q.norm(), z.norm());
                    }
                }
            }
        }
    }

    #[test]
    fn least_distance_says_when_no_point_satisfies_the_rows() {
        // z ≥ 1 and −z ≥ 1 cannot both hold.
        let e = DMatrix::from_row_slice(2, 1, &[1.0, -1.0]);
        let f = DVector::from_vec(vec![1.0, 1.0]);
        assert!(least_distance(&e, &f).is_none());
        // The nearest point of z ≥ 1, z ≤ 3 is 1.
        let f = DVector::from_vec(vec![1.0, -3.0]);
        let z = least_distance(&e, &f).expect("feasible");
        assert!((z[0] - 1.0).abs() < 1e-12, "{}", z[0]);
    }
}
