//! The bivariate reduction f(θh, θd) of an isotropic BRDF (Romero et al. 2008): a 90 × 90 grid
//! per colour channel, 24,300 values in all.
//!
//! Two choices are recorded with every grid, and measured in `eval`: how θh is binned (MERL's
//! square-root bins or uniform bins) and how φd is removed (the mean over the φd cells that were
//! measured, or the φd = 90° slice). Cells with no measured φd hold zero and are flagged invalid.

use serde::{Deserialize, Serialize};

use super::brdf::{add, angle_between, normalize, IsotropicBrdf, Vec3};
use super::merl::{self, MerlBrdf};

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
    /// most of their work at each sample (a tenth of the cost of `N` reductions, for
    /// OpenPBR's five parts).
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

impl IsotropicBrdf for Bivariate {
    fn eval_angles(&self, theta_h: f64, theta_d: f64, _phi_d: f64) -> [f64; 3] {
        self.cell(
            self.grid.theta_h_binning.bin(theta_h),
            merl::theta_d_bin(theta_d),
        )
    }

    /// θh and θd only, straight from the half vector: the table does not vary with φd, so
    /// the frame that gives it is not worked out (the bounce's grids evaluate millions).
    fn eval_dirs(&self, wi: Vec3, wo: Vec3) -> [f64; 3] {
        if wi[2] <= 0.0 || wo[2] <= 0.0 {
            return [0.0; 3];
        }
        let h = normalize(add(wi, wo));
        self.eval_angles(angle_between(h, [0.0, 0.0, 1.0]), angle_between(wi, h), 0.0)
    }
}
