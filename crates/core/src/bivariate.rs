//! The bivariate reduction f(θh, θd) of an isotropic BRDF (Romero et al. 2008): a 90 × 90 grid
//! per colour channel, 24,300 values in all.
//!
//! Two choices are recorded with every grid, and measured in `eval`: how θh is binned (MERL's
//! square-root bins or uniform bins) and how φd is removed (the mean over the φd cells that were
//! measured, or the φd = 90° slice). Cells with no measured φd hold zero and are flagged invalid.

use serde::{Deserialize, Serialize};

use super::brdf::{add, normalize, IsotropicBrdf, Vec3};
use super::merl::{self, MerlBrdf};
use super::render::BinLut;

pub const N_THETA_H: usize = 90;
pub const N_THETA_D: usize = 90;
/// Cells per channel.
pub const GRID_CELLS: usize = N_THETA_H * N_THETA_D;
/// Values per material: three channels of the grid, channel-planar.
pub const VALUES: usize = 3 * GRID_CELLS;
const HALF_PI: f64 = std::f64::consts::FRAC_PI_2;
/// φd samples over [0, π/2): for an isotropic, reciprocal BRDF f(φd) = f(π − φd), so the
/// quarter turn stands for the half turn MERL stores, at the same 1° spacing.
const PHI_SAMPLES: usize = merl::PHI_D_BINS / 2;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ThetaHBinning {
    /// MERL's bins, uniform in √θh: fine near the specular peak.
    Sqrt,
    /// Uniform 1° bins.
    Uniform,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PhiReduction {
    /// Mean over the measured φd cells.
    ValidMean,
    /// The φd = 90° slice.
    Slice90,
}

/// How a bivariate grid was made; recorded in basis files.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Grid {
    pub theta_h_binning: ThetaHBinning,
    pub phi_reduction: PhiReduction,
}

impl Default for Grid {
    /// The choice `brdfd eval --choices` measured best (see docs/evaluation.md, "Measured choices").
    fn default() -> Self {
        Grid {
            theta_h_binning: ThetaHBinning::Sqrt,
            phi_reduction: PhiReduction::ValidMean,
        }
    }
}

impl ThetaHBinning {
    pub fn bin(self, theta_h: f64) -> usize {
        match self {
            ThetaHBinning::Sqrt => merl::theta_h_bin(theta_h),
            ThetaHBinning::Uniform => merl::theta_d_bin(theta_h),
        }
    }

    pub fn center(self, i: usize) -> f64 {
        match self {
            ThetaHBinning::Sqrt => merl::theta_h_center(i),
            ThetaHBinning::Uniform => merl::theta_d_center(i),
        }
    }

    /// Lower edge of bin `i` (bin 0 starts at 0).
    pub(crate) fn lower_edge(self, i: usize) -> f64 {
        let s = i as f64 / N_THETA_H as f64;
        match self {
            ThetaHBinning::Sqrt => s * s * HALF_PI,
            ThetaHBinning::Uniform => s * HALF_PI,
        }
    }
}

pub(crate) fn theta_d_lower_edge(j: usize) -> f64 {
    j as f64 / N_THETA_D as f64 * HALF_PI
}

/// Index of a grid cell within one channel plane: θh major, θd minor (an image with θh down
/// the rows and θd across the columns, as in the paper's Fig. 3).
pub(crate) fn grid_index(ih: usize, jd: usize) -> usize {
    ih * N_THETA_D + jd
}

/// A bivariate BRDF on the grid, in 1/sr.
#[derive(Clone, Debug)]
pub struct Bivariate {
    pub grid: Grid,
    /// Channel-planar: `values[c * GRID_CELLS + grid_index(ih, jd)]`.
    pub values: Vec<f64>,
    /// Per grid cell: whether any φd of it was measured.
    pub valid: Vec<bool>,
}

impl Bivariate {
    /// Reduces a full BRDF to the grid.
    pub fn reduce(source: &dyn IsotropicBrdf, grid: Grid) -> Self {
        let [one] = Bivariate::reduce_parts(grid, |th, td, pd| {
            source
                .measured(th, td, pd)
                .then(|| [source.eval_angles(th, td, pd)])
        });
        one
    }

    /// Reduces `N` BRDFs to the grid in one pass, `eval` giving each one's value at
    /// (θh, θd, φd), or `None` where none is measured: the parts of one material, which share
    /// most of their work at each sample.
    pub fn reduce_parts<const N: usize>(
        grid: Grid,
        eval: impl Fn(f64, f64, f64) -> Option<[[f64; 3]; N]> + Sync,
    ) -> [Bivariate; N] {
        use rayon::prelude::*;
        let cells: Vec<Option<[[f64; 3]; N]>> = (0..GRID_CELLS)
            .into_par_iter()
            .map(|g| {
                let (ih, jd) = (g / N_THETA_D, g % N_THETA_D);
                let th = grid.theta_h_binning.center(ih);
                let td = merl::theta_d_center(jd);
                match grid.phi_reduction {
                    PhiReduction::Slice90 => eval(th, td, HALF_PI),
                    PhiReduction::ValidMean => {
                        let mut sum = [[0.0; 3]; N];
                        let mut n = 0usize;
                        for k in 0..PHI_SAMPLES {
                            if let Some(v) = eval(th, td, merl::phi_d_center(k)) {
                                for (s, v) in sum.iter_mut().zip(&v) {
                                    for c in 0..3 {
                                        s[c] += v[c];
                                    }
                                }
                                n += 1;
                            }
                        }
                        (n > 0).then(|| sum.map(|s| s.map(|s| s / n as f64)))
                    }
                }
            })
            .collect();
        std::array::from_fn(|part| {
            let mut values = vec![0.0; VALUES];
            let mut valid = vec![false; GRID_CELLS];
            for (g, cell) in cells.iter().enumerate() {
                if let Some(parts) = cell {
                    valid[g] = true;
                    for c in 0..3 {
                        values[c * GRID_CELLS + g] = parts[part][c];
                    }
                }
            }
            Bivariate {
                grid,
                values,
                valid,
            }
        })
    }

    pub fn from_values(grid: Grid, values: Vec<f64>, valid: Vec<bool>) -> Self {
        debug_assert_eq!(values.len(), VALUES);
        Bivariate {
            grid,
            values,
            valid,
        }
    }

    pub fn cell(&self, ih: usize, jd: usize) -> [f64; 3] {
        let g = grid_index(ih, jd);
        [
            self.values[g],
            self.values[GRID_CELLS + g],
            self.values[2 * GRID_CELLS + g],
        ]
    }

    /// Expands to a full MERL table: the same value for every φd, and cells below the horizon
    /// marked not measured, so that any MERL-reading renderer can use the result.
    pub fn to_merl(&self) -> MerlBrdf {
        MerlBrdf::from_cells(|ih, jd, kp| {
            let (th, td, pd) = (
                merl::theta_h_center(ih),
                merl::theta_d_center(jd),
                merl::phi_d_center(kp),
            );
            if !super::brdf::above_horizon(th, td, pd) {
                return [
                    -merl::CHANNEL_SCALE[0],
                    -merl::CHANNEL_SCALE[1],
                    -merl::CHANNEL_SCALE[2],
                ];
            }
            let own = self.grid.theta_h_binning.bin(th);
            self.cell(own, jd).map(|v| v.max(0.0))
        })
    }
}

/// The θh and θd bin tables of `binning`, made once per process.
fn bin_luts(binning: ThetaHBinning) -> &'static (BinLut, BinLut) {
    use std::sync::OnceLock;
    static SQRT: OnceLock<(BinLut, BinLut)> = OnceLock::new();
    static UNIFORM: OnceLock<(BinLut, BinLut)> = OnceLock::new();
    let cell = match binning {
        ThetaHBinning::Sqrt => &SQRT,
        ThetaHBinning::Uniform => &UNIFORM,
    };
    cell.get_or_init(|| (BinLut::theta_h(binning), BinLut::theta_d()))
}

impl IsotropicBrdf for Bivariate {
    fn eval_angles(&self, theta_h: f64, theta_d: f64, _phi_d: f64) -> [f64; 3] {
        self.cell(
            self.grid.theta_h_binning.bin(theta_h),
            merl::theta_d_bin(theta_d),
        )
    }

    /// θh's and θd's bins only, straight from the half vector: the table does not vary with
    /// φd, so the frame that gives it is not worked out, and the bins are read from the
    /// squared chords |h − n|² and |ωi − h|² by the renderers' tables ([`BinLut`]) instead of
    /// from the angles (two arctangents a call; the bounce's grids evaluate millions).
    fn eval_dirs(&self, wi: Vec3, wo: Vec3) -> [f64; 3] {
        if wi[2] <= 0.0 || wo[2] <= 0.0 {
            return [0.0; 3];
        }
        let h = normalize(add(wi, wo));
        // Differences, not 2 − 2 cos θ: near the peak the cosine's rounding would swamp
        // the first bins.
        let chord2 = |a: Vec3, b: Vec3| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>() as f32;
        let luts = bin_luts(self.grid.theta_h_binning);
        self.cell(
            luts.0.bin(chord2(h, [0.0, 0.0, 1.0])),
            luts.1.bin(chord2(wi, h)),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{dot, fibonacci_sphere};

    #[test]
    fn directions_read_the_cells_their_angles_do() {
        // A table holding each cell's own index, read through `eval_dirs` (the bins of the
        // squared chords, by the renderers' tables) and through `eval_angles` at the pair's
        // angles, for pairs spread over the hemisphere: the same cell, but within a
        // millionth of a radian of a bin's edge, where an f32 chord and an f64 angle may round
        // apart.
        let upper: Vec<Vec3> = fibonacci_sphere(400)
            .into_iter()
            .filter(|d| d[2] > 0.0)
            .collect();
        for binning in [ThetaHBinning::Sqrt, ThetaHBinning::Uniform] {
            let grid = Grid {
                theta_h_binning: binning,
                phi_reduction: PhiReduction::ValidMean,
            };
            let values = (0..VALUES).map(|i| (i % GRID_CELLS) as f64).collect();
            let table = Bivariate::from_values(grid, values, vec![true; GRID_CELLS]);
            let near_edge = |theta: f64, edges: &dyn Fn(usize) -> f64| {
                (0..N_THETA_H).any(|b| (theta - edges(b)).abs() < 1e-6)
            };
            let mut checked = 0;
            for wi in &upper {
                for wo in &upper {
                    let h = normalize(add(*wi, *wo));
                    let theta_h = h[2].clamp(-1.0, 1.0).acos();
                    let theta_d = dot(*wi, h).clamp(-1.0, 1.0).acos();
                    if near_edge(theta_h, &|b| binning.lower_edge(b))
                        || near_edge(theta_d, &theta_d_lower_edge)
                    {
                        continue;
                    }
                    assert_eq!(
                        table.eval_dirs(*wi, *wo),
                        table.eval_angles(theta_h, theta_d, 0.0),
                        "{binning:?}: θh {theta_h}, θd {theta_d}"
                    );
                    checked += 1;
                }
            }
            assert!(checked > 30_000, "{checked}");
        }
    }
}
