//! The hybrid model: the analytic model's Lambert and GGX lobes ([`super::analytic`]) plus a
//! non-negative mix of measured materials (the basis's training set, [`Basis::atoms`]),
//! fitted jointly to the photo.
//!
//! ```text
//! f = kd/π + Σₗ lobeₗ(αₗ) · (F₀ₗ (1 − w) + F₉₀ₗ w) + Σₘ aₘ · fₘ,   every weight ≥ 0,
//! ```
//!
//! per colour channel, with fₘ the measured material m's table in that channel. Why: the
//! analytic model extrapolates well from the angles a photo sees to the ones it does not, but
//! a real material's shape (a paint's flake, a fabric's sheen, a plastic's two-part peak) is
//! not a GGX lobe; the measured materials hold those shapes, and the lobes hold peaks sharper
//! than any of them. Every column is non-negative and a function of (θh, θd), so the estimate
//! is non-negative and reciprocal by construction, with no clamp afterwards.
//!
//! The roughnesses come from the analytic model's search ([`analytic::roughnesses`]), with each
//! set tried scored with every weight solved; the weights, by non-negative least squares, keep
//! few materials (a sparse mix). They are solved on the search's spread pixels
//! ([`analytic::SEARCH_PIXELS`]); the fit to the photo is measured over every candidate.

use std::borrow::Cow;

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::analytic::{self, Microfacet, ViewPixels};
use super::basis::Basis;
use super::bivariate::{Bivariate, Grid, GRID_CELLS, VALUES};
use super::envmap::LightSet;
use super::error::{CoreError, Result};
use super::geometry::GeomPixel;
use super::nnls::nnls;
use super::render::{RenderingMatrix, PASS_COLUMNS};
use super::solve::{relative_misfit, CHANNELS};
use super::stop::Stop;
use super::uncertainty::{band, image_spread, resamples, spread_sphere, std_of, Uncertainty};

/// One measured material in the mix and its weight per channel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MixWeight {
    pub material: String,
    pub weight: [f64; 3],
}

/// What [`fit`] renders before it needs the photo: the measured materials' rows and the
/// roughness search's coarse grid ([`analytic::CoarseRenders`]) on the search pixels. Made
/// while a camera shoots from the pixels the estimate will take if the photo leaves none out;
/// the fit uses them only when its pixels, lights, grid and measured materials turn out to be
/// those.
pub struct Prepared {
    coarse: analytic::CoarseRenders,
    /// The measured materials the rows are of, names and tables: a basis id names its
    /// training data but not its tables. Kept whole rather than as a digest: comparing them
    /// with the fit's takes a few milliseconds, where hashing them took about 18, on the
    /// capture's way to its results. The copy (17 MB for the default basis) is made while the
    /// camera shoots, and lives as long as the estimate.
    atoms: (Vec<String>, Vec<Vec<f64>>),
    atom_rows: Vec<f64>,
    /// Per channel, the rows' Gram matrix ([`Mix`]'s): it needs no photo either.
    atom_gram: [DMatrix<f64>; 3],
}

impl Prepared {
    /// For views with these candidate pixels under these lights.
    pub fn new(views: &[(&[GeomPixel], &LightSet)], basis: &Basis, stop: &Stop) -> Result<Self> {
        let grid = basis.header.grid;
        let coarse = analytic::CoarseRenders::new(views, grid, stop)?;
        let atoms: Vec<&[f64]> = basis.atoms().map(|(_, t)| t).collect();
        let atom_rows = coarse
            .view_pixels()
            .iter()
            .zip(views)
            .map(|(px, (_, lights))| dense_rows(px, lights, &atoms, grid, stop))
            .collect::<Result<Vec<_>>>()?
            .concat();
        let atom_gram = Mix::grams(&atom_rows, atoms.len());
        Ok(Prepared {
            coarse,
            atoms: (basis.header.materials.clone(), basis.atoms.clone()),
            atom_rows,
            atom_gram,
        })
    }
}

/// The fit of [`fit`].
#[derive(Clone, Debug)]
pub struct HybridFit {
    /// The analytic part: Lambert and the lobes with their weights from the joint fit.
    pub analytic: Microfacet,
    /// The measured materials kept (a weight above zero in some channel), in the basis's order.
    pub mixture: Vec<MixWeight>,
    pub brdf: Bivariate,
    /// Names of [`HybridFit::coefficients`]: the analytic part's ([`Microfacet::names`]), then
    /// `<material>.R`, `.G`, `.B` per material kept.
    pub names: Vec<String>,
    pub coefficients: Vec<f64>,
    /// ‖A·c − y‖/‖y‖ over every candidate.
    pub fit_error: f64,
    /// ‖A·c − y‖/‖y‖ over the pixels the weights were solved on.
    pub solved_misfit: f64,
    /// Pixels the weights were solved on.
    pub solved: usize,
    /// Candidates the fit error was measured on.
    pub candidates: usize,
    /// What the fit renders at each candidate, three values (R, G, B) per candidate, every
    /// view's in turn.
    pub predicted: Vec<f64>,
    /// κ of the per-channel systems over the columns kept (the worst channel's), columns
    /// scaled to unit norm.
    pub condition: f64,
    pub uncertainty: Uncertainty,
    /// Whether [`Prepared`] renders were used.
    pub prepared: bool,
}

impl HybridFit {
    /// The BRDF of an analytic part and a mix, with the measured tables of `basis`: what
    /// `brdfd render --coefficients` rebuilds from `coefficients.json`.
    pub fn rebuild(
        analytic: &Microfacet,
        mixture: &[MixWeight],
        basis: &Basis,
    ) -> std::result::Result<Bivariate, String> {
        if !mixture.is_empty() && basis.atoms.is_empty() {
            return Err(format!(
                "the basis {} holds no measured materials; pass the basis the estimate was made with (--basis), or one rebuilt by this brdfd's `basis build`",
                basis.header.id
            ));
        }
        let mut brdf = analytic.bivariate(basis.header.grid);
        for m in mixture {
            let (_, table) = basis
                .atoms()
                .find(|(n, _)| *n == m.material)
                .ok_or_else(|| format!("the basis has no measured material {}", m.material))?;
            if m.weight.iter().any(|w| !w.is_finite() || *w < 0.0) {
                return Err(format!("material {}: weights must be ≥ 0", m.material));
            }
            for c in 0..3 {
                let plane = c * GRID_CELLS..(c + 1) * GRID_CELLS;
                for (v, x) in brdf.values[plane.clone()].iter_mut().zip(&table[plane]) {
                    *v += m.weight[c] * x;
                }
            }
        }
        Ok(brdf)
    }
}

/// Dense rows of the rendering matrix of `columns` for `pixels`, built [`PASS_COLUMNS`] at a
/// time: row (3·p + c) holds every column's value for pixel p, channel c.
fn dense_rows(
    pixels: &[GeomPixel],
    lights: &LightSet,
    columns: &[&[f64]],
    grid: Grid,
    stop: &Stop,
) -> Result<Vec<f64>> {
    let n = columns.len();
    let mut rows = vec![0.0; 3 * pixels.len() * n];
    for (k, chunk) in columns.chunks(PASS_COLUMNS).enumerate() {
        stop.check()?;
        let a = RenderingMatrix::build(pixels, lights, chunk, None, grid.theta_h_binning);
        for r in 0..3 * pixels.len() {
            for (j, v) in a.row(r).iter().enumerate() {
                rows[r * n + k * PASS_COLUMNS + j] = *v as f64;
            }
        }
    }
    Ok(rows)
}

/// Per channel, the Gram matrix and right-hand side of the columns `cols` over the pixels
/// `picks` (repeats count twice: a bootstrap resample), and yᵀy.
fn systems(
    rows: &[f64],
    n: usize,
    observed: &[[f64; 3]],
    picks: &[usize],
    cols: &[usize],
) -> [(DMatrix<f64>, DVector<f64>, f64); 3] {
    std::array::from_fn(|c| {
        analytic::normal_equations(cols.len(), picks.len(), |r, x| {
            let p = picks[r];
            let row = &rows[(3 * p + c) * n..(3 * p + c + 1) * n];
            for (xi, &k) in x.iter_mut().zip(cols) {
                *xi = row[k];
            }
            observed[p][c]
        })
    })
}

/// Lambert's column, then each lobe's F₀ and F₉₀ columns.
fn lobe_refs(cols: &[[Vec<f64>; 3]]) -> Vec<&[f64]> {
    std::iter::once(cols[0][0].as_slice())
        .chain(cols.iter().flat_map(|l| [l[1].as_slice(), l[2].as_slice()]))
        .collect()
}

/// The measured materials' part of the per-channel systems, computed once: their rows on the
/// mix pixels, their Gram blocks and right-hand sides. [`Mix::solve`] adds the lobes' rows.
struct Mix<'r> {
    /// The materials' rows: the prepared ones are read in place.
    rows: Cow<'r, [f64]>,
    na: usize,
    observed: Vec<[f64; 3]>,
    aa: [DMatrix<f64>; 3],
    ba: [DVector<f64>; 3],
    yy: [f64; 3],
}

impl<'r> Mix<'r> {
    /// The mix of `na` materials with these rows on the pixels that measured `observed`; with
    /// the rows' Gram matrices ([`Mix::grams`]) if they were worked out beforehand.
    fn new(
        rows: Cow<'r, [f64]>,
        na: usize,
        observed: &[[f64; 3]],
        grams: Option<[DMatrix<f64>; 3]>,
    ) -> Mix<'r> {
        let grams = grams.unwrap_or_else(|| Mix::grams(&rows, na));
        let [(b0, y0), (b1, y1), (b2, y2)] = std::array::from_fn(|c| {
            analytic::right_hand_side(na, observed.len(), |p, x| {
                x.copy_from_slice(&rows[(3 * p + c) * na..(3 * p + c + 1) * na]);
                observed[p][c]
            })
        });
        Mix {
            rows,
            na,
            observed: observed.to_vec(),
            aa: grams,
            ba: [b0, b1, b2],
            yy: [y0, y1, y2],
        }
    }

    /// Per channel, the Gram matrix of `na` materials' rows: what needs no photo of the
    /// normal equations, the same to the bit as theirs ([`analytic::normal_equations`]).
    fn grams(rows: &[f64], na: usize) -> [DMatrix<f64>; 3] {
        // No materials (a basis without them): empty matrices, and the fit's own error.
        let pixels = if na == 0 { 0 } else { rows.len() / (3 * na) };
        std::array::from_fn(|c| {
            let (g, _, _) = analytic::normal_equations(na, pixels, |p, x| {
                x.copy_from_slice(&rows[(3 * p + c) * na..(3 * p + c + 1) * na]);
                0.0
            });
            g
        })
    }

    /// The non-negative weights per channel, lobes' columns (`nl` of them, rows `lobe_rows`)
    /// first, and the relative misfit over every channel.
    fn solve(&self, lobe_rows: &[f64], nl: usize) -> ([DVector<f64>; 3], f64) {
        let (na, m) = (self.na, nl + self.na);
        let (mut r2, mut y2) = (0.0, 0.0);
        let weights = std::array::from_fn(|c| {
            let mut g = DMatrix::zeros(m, m);
            let mut b = DVector::zeros(m);
            g.view_mut((nl, nl), (na, na)).copy_from(&self.aa[c]);
            b.rows_mut(nl, na).copy_from(&self.ba[c]);
            // Column i of a lobe: its products with the lobes up to it (the upper triangle)
            // and with the materials, each a contiguous run of the column-major storage, so
            // the loop is plain slices whatever the compiler inlines (it is the hybrid fit's
            // hottest after the rendering kernel).
            let gs = g.as_mut_slice();
            for (p, obs) in self.observed.iter().enumerate() {
                let r = 3 * p + c;
                let l = &lobe_rows[r * nl..(r + 1) * nl];
                let a = &self.rows[r * na..(r + 1) * na];
                for (i, &li) in l.iter().enumerate() {
                    b[i] += li * obs[c];
                    let column = &mut gs[i * m..(i + 1) * m];
                    for (g, lj) in column[..=i].iter_mut().zip(l) {
                        *g += li * lj;
                    }
                    for (g, x) in column[nl..].iter_mut().zip(a) {
                        *g += li * x;
                    }
                }
            }
            // The rest by symmetry: the lobes' lower triangle, and the lobes' rows of the
            // materials' columns.
            for i in 0..nl {
                for j in 0..i {
                    g[(i, j)] = g[(j, i)];
                }
                for j in nl..m {
                    g[(i, j)] = g[(j, i)];
                }
            }
            let w = nnls(&g, &b);
            // ‖Xw − y‖² = wᵀGw − 2wᵀb + yᵀy.
            r2 += ((w.transpose() * &g * &w)[0] - 2.0 * w.dot(&b) + self.yy[c]).max(0.0);
            y2 += self.yy[c];
            w
        });
        (weights, (r2 / y2.max(f64::MIN_POSITIVE)).sqrt())
    }

    /// Dense rows with the lobes' columns (`nl`) first, then the materials'.
    fn joined(&self, lobe_rows: &[f64], nl: usize) -> Vec<f64> {
        lobe_rows
            .chunks(nl)
            .zip(self.rows.chunks(self.na))
            .flat_map(|(l, a)| l.iter().chain(a).copied())
            .collect()
    }
}

/// Fits the hybrid model to the candidates of every view on the analytic model's search pixels
/// ([`analytic::SEARCH_PIXELS`], spread over them: the measured materials make about a hundred
/// columns, and every candidate of a 16-megapixel photo would cost a hundred matrix passes,
/// while 4,000 pixels still give about 40 equations per unknown): its roughness search (`lobes` lobes), with every weight, the lobes' and
/// the materials', solved for each roughness set tried; then the weights of the best.
pub fn fit(
    views: &[ViewPixels],
    basis: &Basis,
    lobes: usize,
    prepared: Option<&Prepared>,
    stop: &Stop,
) -> Result<HybridFit> {
    if basis.atoms.is_empty() {
        return Err(CoreError::Invalid(format!(
            "the basis {} holds no measured materials, which the hybrid model mixes; rebuild it with this brdfd's `basis build`, or use --model analytic",
            basis.header.id
        )));
    }
    let grid = basis.header.grid;
    let names: Vec<&str> = basis.atoms().map(|(n, _)| n).collect();
    let atom_columns: Vec<&[f64]> = basis.atoms().map(|(_, t)| t).collect();

    // The mix is solved on the roughness search's pixels: the materials' rows are built once,
    // and each roughness set tried adds only its lobes'.
    let (pixel_sets, observed) = analytic::search_pixels(views);
    let prepared = prepared.filter(|p| {
        p.atom_rows.len() == 3 * observed.len() * atom_columns.len()
            && p.coarse.is_for(&pixel_sets, views, grid)
            && p.atoms.0 == basis.header.materials
            && p.atoms.1 == basis.atoms
    });
    let (atom_rows, atom_gram) = match prepared {
        Some(p) => (Cow::Borrowed(&p.atom_rows[..]), Some(p.atom_gram.clone())),
        None => {
            let rows = pixel_sets
                .iter()
                .zip(views)
                .map(|(px, v)| dense_rows(px, v.lights, &atom_columns, grid, stop))
                .collect::<Result<Vec<_>>>()?
                .concat();
            (Cow::Owned(rows), None)
        }
    };
    let mix = Mix::new(atom_rows, atom_columns.len(), &observed, atom_gram);
    // Variable projection over the whole model: each roughness set is scored with every weight
    // (lobes and materials) solved, so a lobe need not cover what a material does.
    let score: analytic::Scorer = Box::new(|a: &RenderingMatrix, cols: &[usize]| {
        let rows: Vec<f64> = (0..a.pixels.len() * 3)
            .flat_map(|r| {
                let row = a.row(r);
                cols.iter().map(move |&j| row[j] as f64)
            })
            .collect();
        mix.solve(&rows, cols.len()).1
    });
    let coarse = prepared.map(|p| &p.coarse);
    let found = analytic::roughnesses(views, grid, lobes, Some(score), coarse, stop)?;
    let alphas: Vec<f64> = found.lobes.iter().map(|(alpha, _)| *alpha).collect();
    let alpha_std: Vec<f64> = found.lobes.iter().map(|(_, std)| *std).collect();
    let lobe_cols: Vec<[Vec<f64>; 3]> =
        alphas.iter().map(|a| analytic::columns(grid, *a)).collect();
    let mut columns = lobe_refs(&lobe_cols);
    let lobe_rows = found.rows;
    let (weights, solved_misfit) = mix.solve(&lobe_rows, columns.len());
    let analytic_cols = columns.len();
    columns.extend(&atom_columns);
    let n = columns.len();
    let rows = mix.joined(&lobe_rows, analytic_cols);
    let all: Vec<usize> = (0..observed.len()).collect();

    let brdf = combine(&columns, &weights, grid);
    // Fit to the photo over every candidate: the estimate's own table as one column.
    let mut predicted = Vec::new();
    let mut all_observed = Vec::new();
    for v in views {
        stop.check()?;
        let a = RenderingMatrix::build(
            v.pixels,
            v.lights,
            &[&brdf.values],
            None,
            grid.theta_h_binning,
        );
        predicted.extend(a.predict(&[1.0]));
        all_observed.extend_from_slice(v.observed);
    }
    let fit_error = relative_misfit(&predicted, &all_observed);

    // The columns the fit keeps in some channel: the analytic ones always, the materials with
    // a weight. The uncertainty is measured over these.
    let kept: Vec<usize> = (0..n)
        .filter(|&j| j < analytic_cols || weights.iter().any(|w| w[j] > 0.0))
        .collect();
    let analytic_part = Microfacet::from_weights(&weights, &alphas);
    let mixture: Vec<MixWeight> = kept
        .iter()
        .filter(|&&j| j >= analytic_cols)
        .map(|&j| MixWeight {
            material: names[j - analytic_cols].to_string(),
            weight: std::array::from_fn(|c| weights[c][j]),
        })
        .collect();
    let mut coefficient_names = analytic_part.names();
    let mut coefficients = analytic_part.values();
    for m in &mixture {
        for (c, ch) in CHANNELS.iter().enumerate() {
            coefficient_names.push(format!("{}.{ch}", m.material));
            coefficients.push(m.weight[c]);
        }
    }
    let kept_systems = systems(&rows, n, &observed, &all, &kept);
    let condition = kept_systems
        .iter()
        .map(|(g, _, _)| analytic::scaled_condition(g))
        .fold(0.0, f64::max);
    let uncertainty = uncertainty(
        Inputs {
            rows: &rows,
            n,
            observed: &observed,
            columns: &columns,
            kept: &kept,
            weights: &weights,
            analytic_cols,
            alpha_std: &alpha_std,
            grid,
            lights: views[0].lights,
            stop,
        },
        &kept_systems,
    )?;
    Ok(HybridFit {
        analytic: analytic_part,
        mixture,
        brdf,
        names: coefficient_names,
        coefficients,
        fit_error,
        solved_misfit,
        solved: observed.len(),
        candidates: all_observed.len(),
        predicted,
        condition,
        uncertainty,
        prepared: prepared.is_some(),
    })
}

/// The BRDF Σⱼ wⱼ · columnⱼ per channel (one weight per column), with the grid's valid cells.
fn combine(columns: &[&[f64]], weights: &[DVector<f64>; 3], grid: Grid) -> Bivariate {
    let mut values = vec![0.0; VALUES];
    for c in 0..3 {
        let plane = c * GRID_CELLS..(c + 1) * GRID_CELLS;
        for (column, &w) in columns.iter().zip(weights[c].iter()) {
            if w == 0.0 {
                continue;
            }
            for (v, x) in values[plane.clone()].iter_mut().zip(&column[plane.clone()]) {
                *v += w * x;
            }
        }
    }
    // Lambert's column (the first) is 1/π exactly where the grid has a cell.
    let valid = columns[0][..GRID_CELLS].iter().map(|v| *v > 0.0).collect();
    Bivariate::from_values(grid, values, valid)
}

/// What [`uncertainty`] measures from.
struct Inputs<'a> {
    rows: &'a [f64],
    n: usize,
    observed: &'a [[f64; 3]],
    columns: &'a [&'a [f64]],
    kept: &'a [usize],
    weights: &'a [DVector<f64>; 3],
    analytic_cols: usize,
    /// Each lobe's α 1-σ, from the analytic search's misfit profile.
    alpha_std: &'a [f64],
    grid: Grid,
    lights: &'a LightSet,
    stop: &'a Stop,
}

/// The hybrid fit's [`Uncertainty`]: the kept weights' linearised covariance σ²(XᵀX)⁻¹ per
/// channel (a weight held at zero gets 0), each α's variance from the analytic fit, and a
/// bootstrap over the pixels with the kept columns, which gives the BRDF's band and the relit
/// sphere's spread.
fn uncertainty(
    i: Inputs,
    kept_systems: &[(DMatrix<f64>, DVector<f64>, f64); 3],
) -> Result<Uncertainty> {
    let k = i.kept.len();
    let pixels = i.observed.len();
    // Coefficient positions: the analytic part as Microfacet::values orders it (kd RGB, then
    // per lobe F₀ RGB, F₉₀ RGB, α), then each kept material's R, G, B.
    let analytic_len = 3 + 7 * i.alpha_std.len();
    let position = |c: usize, kk: usize| -> usize {
        let j = i.kept[kk];
        if j == 0 {
            c
        } else if j < i.analytic_cols {
            let (lobe, part) = ((j - 1) / 2, (j - 1) % 2);
            3 + 7 * lobe + 3 * part + c
        } else {
            analytic_len + 3 * (kk - i.analytic_cols) + c
        }
    };
    let m = analytic_len + 3 * (k - i.analytic_cols);
    let mut covariance = vec![0.0; m * m];
    for c in 0..3 {
        let (g, b, yy) = &kept_systems[c];
        let w = DVector::from_fn(k, |kk, _| i.weights[c][i.kept[kk]]);
        let cov = analytic::linearised_covariance(g, b, *yy, &w, pixels);
        for ka in 0..k {
            for kb in 0..k {
                covariance[position(c, ka) * m + position(c, kb)] = cov[(ka, kb)];
            }
        }
    }
    for (l, s) in i.alpha_std.iter().enumerate() {
        let at = 9 + 7 * l;
        covariance[at * m + at] = s * s;
    }
    // Bootstrap with the roughnesses held and the materials the fit left at zero dropped: a
    // resample re-weighs the mix the photo chose, which is what its steadiness is about, at the
    // cost of a dozen columns instead of a hundred.
    let kept_columns: Vec<&[f64]> = i.kept.iter().map(|&j| i.columns[j]).collect();
    let sphere = dense_rows(&spread_sphere()?, i.lights, &kept_columns, i.grid, i.stop)?;
    let image = |w: &[DVector<f64>; 3]| -> Vec<f64> {
        sphere
            .chunks(k)
            .enumerate()
            .map(|(r, row)| row.iter().zip(w[r % 3].iter()).map(|(x, v)| x * v).sum())
            .collect()
    };
    let own = |c: usize| DVector::from_fn(k, |kk, _| i.weights[c][i.kept[kk]]);
    let fitted: [DVector<f64>; 3] = std::array::from_fn(own);
    // The resamples drawn in order from one seed, then solved side by side: each needs
    // nothing of the others.
    let (brdfs, images): (Vec<Vec<f64>>, Vec<Vec<f64>>) = resamples(pixels)
        .par_iter()
        .map(|picks| {
            let s = systems(i.rows, i.n, i.observed, picks, i.kept);
            let w: [DVector<f64>; 3] = std::array::from_fn(|c| nnls(&s[c].0, &s[c].1));
            (combine(&kept_columns, &w, i.grid).values, image(&w))
        })
        .unzip();
    Ok(Uncertainty {
        std: std_of(&covariance, m),
        covariance,
        covariance_from: "linearised",
        bootstrap_spread: image_spread(&images, &image(&fitted)),
        resamples: images.len(),
        band: band(&brdfs),
    })
}
