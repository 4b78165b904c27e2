//! The data-driven BRDF basis: PCA of bivariate BRDFs, its file format, and the embedded
//! default built from the 90 training materials of docs/evaluation.md.
//!
//! File format (`brdfd-basis/1`): two files with one stem.
//! - `NAME.exr`: a multi-part OpenEXR, one part per vector, named `mean` (when the basis has
//!   a mean term), `pc01`, `pc02`, … and `atom.<material>`; each part is a 90 × 90 image with
//!   channels R, G, B (unprefixed), θh bins down the rows and θd bins across the columns.
//!   Parts rather than one part's prefixed channels (`pc01.R`): each vector is a whole RGB
//!   image that a viewer shows alone and a reader decodes without the others (OpenEXR's
//!   `exrmultipart -separate` splits them into files), and the atoms can be half floats.
//! - `NAME.json`: the [`BasisHeader`]: materials, K, normalisation, grid, explained variance.
//!
//! Vectors are stored in BRDF units (1/sr), so f ≈ offset + Σ cₖ·bₖ holds with no further
//! scaling; the normalisation only says how the training matrix was scaled before the PCA.

use std::io::Cursor;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::bivariate::{Bivariate, Grid, GRID_CELLS, N_THETA_D, N_THETA_H, VALUES};
use super::envmap::LightSet;
use super::error::{CoreError, Result};
use super::geometry::GeomPixel;
use super::render::RenderingMatrix;

pub const FORMAT: &str = "brdfd-basis/1";
/// K of the shipped basis and of `basis build` unless told otherwise (the paper's choice).
pub const DEFAULT_K: usize = 5;
/// The largest K an estimate can use: the rendering matrix carries at most K + 2 columns
/// (components, mean, offset) in fixed-size arrays, for speed.
pub const MAX_K: usize = super::render::MAX_COLUMNS - 2;
/// Explained variance is reported for K = 1 ..= this.
pub const REPORT_K: usize = 10;

/// How training BRDFs are scaled before the PCA.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Normalisation {
    /// Raw values: specular materials dominate the components.
    None,
    /// Each material divided by its RMS over the grid, so every material weighs the same
    /// ("normalised in real space", as the paper puts it). The material's scale is then
    /// unknown, so the mean becomes a free coefficient of the estimate.
    Rms,
}

/// A fixed weight per grid cell applied before the PCA (the PCA runs on w ⊙ f). It changes
/// which subspace the first K components span, not the linearity of the estimate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CellWeight {
    /// Every cell counts the same: the specular peak and the grazing cells dominate.
    None,
    /// √ of the measure a cell has in a rendering integral, dωᵢ dωₒ ∝ cos θd sin θh sin θd
    /// dθh dθd (Rusinkiewicz's Jacobian), so cells weigh what they weigh in images.
    SolidAngle,
}

impl CellWeight {
    /// Per-cell weights (one channel plane), scaled to mean 1.
    pub fn weights(self, grid: Grid) -> Vec<f64> {
        use super::bivariate::{theta_d_lower_edge, N_THETA_D};
        let mut w = vec![1.0; GRID_CELLS];
        if self == CellWeight::SolidAngle {
            let b = grid.theta_h_binning;
            for ih in 0..N_THETA_H {
                let (h0, h1) = (
                    b.lower_edge(ih),
                    if ih + 1 < N_THETA_H {
                        b.lower_edge(ih + 1)
                    } else {
                        std::f64::consts::FRAC_PI_2
                    },
                );
                let th = 0.5 * (h0 + h1);
                for jd in 0..N_THETA_D {
                    let d0 = theta_d_lower_edge(jd);
                    let d1 = d0 + std::f64::consts::FRAC_PI_2 / N_THETA_D as f64;
                    let td = 0.5 * (d0 + d1);
                    w[ih * N_THETA_D + jd] =
                        (td.cos() * th.sin() * td.sin() * (h1 - h0) * (d1 - d0))
                            .max(0.0)
                            .sqrt();
                }
            }
            let mean = w.iter().sum::<f64>() / w.len() as f64;
            w.iter_mut().for_each(|x| *x /= mean);
        }
        w
    }
}

/// Everything a basis file records besides its vectors.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BasisHeader {
    pub format: String,
    /// A digest of the PCA vectors (mean and components): equal ids mean equal basis models.
    /// The measured materials' tables (`atoms`) are not in it: they are the named training
    /// materials themselves.
    pub id: String,
    pub k: usize,
    pub materials: Vec<String>,
    pub normalisation: Normalisation,
    pub cell_weight: CellWeight,
    /// Whether the model has a mean term (f ≈ b₀ + Σ cₖ bₖ).
    pub mean: bool,
    pub grid: Grid,
    /// Cumulative explained variance for K = 1, 2, …, up to [`REPORT_K`] or the rank.
    pub explained_variance: Vec<f64>,
    /// Standard deviation of each component's score over the training set, in the normalised
    /// space: the prior for the regularised solve.
    pub score_std: Vec<f64>,
    /// Where the vectors live and how they are laid out, for readers without this code.
    pub layout: String,
    /// Whether the EXR also holds each training material's own table (a layer
    /// `atom.<material>` per name in `materials`): the measured materials the hybrid model
    /// mixes. The `id` covers the PCA vectors only, which basis-model coefficients depend on.
    #[serde(default)]
    pub atoms: bool,
}

/// A basis: header plus vectors in BRDF units.
#[derive(Clone, Debug)]
pub struct Basis {
    pub header: BasisHeader,
    /// Mean BRDF (zero vector when the basis has no mean term).
    pub mean: Vec<f64>,
    pub components: Vec<Vec<f64>>,
    /// The training materials' tables in BRDF units, in the order of `header.materials`;
    /// empty if the basis file has none (`header.atoms`).
    pub atoms: Vec<Vec<f64>>,
}

/// The linear model the estimate solves: BRDF = offset + Σ coefficientsⱼ · columnsⱼ.
pub struct LinearModel<'a> {
    pub offset: Option<&'a [f64]>,
    pub columns: Vec<&'a [f64]>,
    pub names: Vec<String>,
}

impl Basis {
    /// PCA of the given bivariate BRDFs. `k` components are kept.
    pub fn build(
        training: &[(String, Bivariate)],
        k: usize,
        normalisation: Normalisation,
        cell_weight: CellWeight,
        mean: bool,
    ) -> Result<Basis> {
        use nalgebra::DMatrix;
        let n = training.len();
        if n < 2 {
            return Err(CoreError::Invalid(format!(
                "a basis needs at least 2 training materials, got {n}"
            )));
        }
        let most = MAX_K.min(n - 1);
        if k == 0 || k > most {
            return Err(CoreError::Invalid(format!(
                "K must be between 1 and {most} (at most {MAX_K}, and fewer than the {n} training materials), got {k}"
            )));
        }
        let grid = training[0].1.grid;
        if let Some((name, _)) = training.iter().find(|(_, b)| b.grid != grid) {
            return Err(CoreError::Invalid(format!(
                "material {name} was reduced on a different grid from {}",
                training[0].0
            )));
        }
        let w = cell_weight.weights(grid);
        let columns: Vec<Vec<f64>> = training
            .iter()
            .map(|(_, b)| {
                let weighted: Vec<f64> = b
                    .values
                    .iter()
                    .enumerate()
                    .map(|(i, v)| v * w[i % GRID_CELLS])
                    .collect();
                match normalisation {
                    Normalisation::None => weighted,
                    Normalisation::Rms => {
                        let rms =
                            (weighted.iter().map(|v| v * v).sum::<f64>() / VALUES as f64).sqrt();
                        weighted
                            .iter()
                            .map(|v| v / rms.max(f64::MIN_POSITIVE))
                            .collect()
                    }
                }
            })
            .collect();
        let mut mean_vec = vec![0.0; VALUES];
        if mean {
            for col in &columns {
                for (m, v) in mean_vec.iter_mut().zip(col) {
                    *m += v / n as f64;
                }
            }
        }
        let centred = DMatrix::from_fn(VALUES, n, |r, c| columns[c][r] - mean_vec[r]);
        // The Gram matrix is n × n (n ≈ 100), far cheaper than a 24,300-row SVD.
        let gram = centred.transpose() * &centred;
        let eig = nalgebra::SymmetricEigen::new(gram);
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let total: f64 = eig.eigenvalues.iter().map(|v| v.max(0.0)).sum();
        let mut explained = Vec::new();
        let mut acc = 0.0;
        for &i in order.iter().take(REPORT_K.min(n)) {
            acc += eig.eigenvalues[i].max(0.0);
            explained.push(acc / total);
        }
        let mut components = Vec::with_capacity(k);
        let mut score_std = Vec::with_capacity(k);
        for &i in order.iter().take(k) {
            let lambda = eig.eigenvalues[i];
            if lambda <= total * 1e-14 {
                return Err(CoreError::Invalid(format!(
                    "the training set has rank below K = {k}; use fewer components"
                )));
            }
            let v = eig.eigenvectors.column(i);
            let mut b = (&centred * v).into_iter().copied().collect::<Vec<f64>>();
            let norm = b.iter().map(|x| x * x).sum::<f64>().sqrt();
            // Sign convention: the largest-magnitude entry is positive, so rebuilds are stable.
            let peak = b
                .iter()
                .copied()
                .fold(0.0f64, |m, x| if x.abs() > m.abs() { x } else { m });
            let sign = if peak < 0.0 { -1.0 } else { 1.0 };
            b.iter_mut().for_each(|x| *x *= sign / norm);
            // Back from the weighted space to BRDF units.
            b.iter_mut()
                .enumerate()
                .for_each(|(i, x)| *x /= w[i % GRID_CELLS]);
            components.push(b);
            score_std.push((lambda / n as f64).sqrt());
        }
        mean_vec
            .iter_mut()
            .enumerate()
            .for_each(|(i, x)| *x /= w[i % GRID_CELLS]);
        let mut header = BasisHeader {
            format: FORMAT.into(),
            id: String::new(),
            k,
            materials: training.iter().map(|(n, _)| n.clone()).collect(),
            normalisation,
            cell_weight,
            mean,
            grid,
            explained_variance: explained,
            score_std,
            layout: layout_text(),
            atoms: true,
        };
        let mut basis = Basis {
            header: header.clone(),
            mean: mean_vec,
            components,
            atoms: training.iter().map(|(_, b)| b.values.clone()).collect(),
        };
        header.id = basis.digest();
        basis.header = header;
        Ok(basis)
    }

    fn digest(&self) -> String {
        let mut h = Sha256::new();
        for v in std::iter::once(&self.mean).chain(&self.components) {
            for x in v {
                h.update((*x as f32).to_le_bytes());
            }
        }
        let d = h.finalize();
        format!(
            "sha256:{}",
            d.iter()
                .take(8)
                .map(|b| format!("{b:02x}"))
                .collect::<String>()
        )
    }

    /// The linear model for estimation (see [`Normalisation::Rms`] for why the mean is a
    /// free column there and a fixed offset otherwise).
    pub fn model(&self) -> LinearModel<'_> {
        let mut columns: Vec<&[f64]> = Vec::new();
        let mut names = Vec::new();
        let mut offset = None;
        if self.header.mean {
            match self.header.normalisation {
                Normalisation::None => offset = Some(self.mean.as_slice()),
                Normalisation::Rms => {
                    columns.push(self.mean.as_slice());
                    names.push("mean".to_string());
                }
            }
        }
        for (i, c) in self.components.iter().enumerate() {
            columns.push(c.as_slice());
            names.push(format!("pc{}", i + 1));
        }
        LinearModel {
            offset,
            columns,
            names,
        }
    }

    /// The rendering matrix of this basis's model for `pixels` under `lights`.
    pub fn rendering_matrix(&self, pixels: &[GeomPixel], lights: &LightSet) -> RenderingMatrix {
        let model = self.model();
        RenderingMatrix::build(
            pixels,
            lights,
            &model.columns,
            model.offset,
            self.header.grid.theta_h_binning,
        )
    }

    /// Standard deviation of each model column's coefficient over the training set, for the
    /// regularised solve. `None` for a column with no prior (the free mean of an RMS basis).
    pub fn column_prior(&self) -> Vec<Option<f64>> {
        let mut out = Vec::new();
        if self.header.mean && self.header.normalisation == Normalisation::Rms {
            out.push(None);
        }
        out.extend(self.header.score_std.iter().map(|s| Some(*s)));
        out
    }

    /// The natural scale of each model column's coefficient, relative to the material's own
    /// scale: 1 for the mean (or an offset-free first column), the training spread σₖ for
    /// component k. Pixel selection works on A·diag(scales), where every coefficient is
    /// equally plausible; otherwise κ mostly measures how differently the columns are scaled.
    pub fn column_scales(&self) -> Vec<f64> {
        self.column_prior()
            .iter()
            .map(|p| p.unwrap_or(1.0))
            .collect()
    }

    /// Reconstructs a bivariate BRDF from model coefficients.
    pub fn reconstruct(&self, coefficients: &[f64]) -> Bivariate {
        let model = self.model();
        let mut values = model
            .offset
            .map(|o| o.to_vec())
            .unwrap_or(vec![0.0; VALUES]);
        for (c, col) in coefficients.iter().zip(&model.columns) {
            for (v, b) in values.iter_mut().zip(col.iter()) {
                *v += c * b;
            }
        }
        let valid = (0..GRID_CELLS)
            .map(|g| {
                (0..3).any(|c| self.mean[c * GRID_CELLS + g] != 0.0)
                    || self
                        .components
                        .iter()
                        .any(|b| (0..3).any(|c| b[c * GRID_CELLS + g] != 0.0))
            })
            .collect();
        Bivariate::from_values(self.header.grid, values, valid)
    }

    /// Reconstructs a solution's BRDF, joint or per channel
    /// ([`channel_coefficients`]); an error if its length
    /// fits neither.
    pub fn reconstruct_solution(&self, coefficients: &[f64]) -> Result<Bivariate> {
        let m = self.model().columns.len();
        let per_channel = channel_coefficients(coefficients, m)?;
        Ok(if coefficients.len() == m {
            self.reconstruct(coefficients)
        } else {
            self.reconstruct_channels(per_channel)
        })
    }

    /// Reconstructs from one coefficient vector per channel: channel c is the basis's
    /// channel-c planes combined with `coefficients[c]`.
    pub fn reconstruct_channels(&self, coefficients: [&[f64]; 3]) -> Bivariate {
        let mut out = self.reconstruct(coefficients[0]);
        for (c, coef) in coefficients.iter().enumerate().skip(1) {
            let plane = c * GRID_CELLS..(c + 1) * GRID_CELLS;
            out.values[plane.clone()].copy_from_slice(&self.reconstruct(coef).values[plane]);
        }
        out
    }

    /// Least-squares projection of a bivariate BRDF onto the model, in the basis's weighted
    /// metric: the best coefficients any estimate could reach, used as ground truth in tests
    /// and the evaluation.
    pub fn project(&self, target: &Bivariate) -> Vec<f64> {
        self.project_rows(target, 0..VALUES)
    }

    /// [`Basis::project`] for a per-channel estimate
    /// ([`Colour::PerChannel`](super::solve::Colour::PerChannel)): each channel projected on
    /// the basis's planes for that channel, the R, G and B coefficients in turn.
    pub fn project_channels(&self, target: &Bivariate) -> Vec<f64> {
        (0..3)
            .flat_map(|c| self.project_rows(target, c * GRID_CELLS..(c + 1) * GRID_CELLS))
            .collect()
    }

    /// Weighted least-squares fit of `target` on the model over the given rows of the grid.
    fn project_rows(&self, target: &Bivariate, rows: std::ops::Range<usize>) -> Vec<f64> {
        let model = self.model();
        let m = model.columns.len();
        let w = self.header.cell_weight.weights(self.header.grid);
        let (n, first) = (rows.len(), rows.start);
        let a = nalgebra::DMatrix::from_fn(n, m, |i, c| {
            let r = first + i;
            model.columns[c][r] * w[r % GRID_CELLS]
        });
        let y = nalgebra::DVector::from_fn(n, |i, _| {
            let r = first + i;
            (target.values[r] - model.offset.map_or(0.0, |o| o[r])) * w[r % GRID_CELLS]
        });
        let svd = a.svd(true, true);
        svd.solve(&y, 1e-12)
            .map(|c| c.iter().copied().collect())
            .unwrap_or_else(|_| vec![0.0; m])
    }

    /// Writes `stem.exr` and `stem.json` (any extension on `path` is replaced).
    pub fn write(&self, path: &Path) -> Result<(PathBuf, PathBuf)> {
        let exr_path = path.with_extension("exr");
        let json_path = path.with_extension("json");
        let bytes = self.exr_bytes()?;
        std::fs::write(&exr_path, bytes).map_err(|e| CoreError::io(&exr_path, e))?;
        let json = serde_json::to_string_pretty(&self.header).expect("header serialises");
        std::fs::write(&json_path, json).map_err(|e| CoreError::io(&json_path, e))?;
        Ok((exr_path, json_path))
    }

    fn layers(&self) -> Vec<(String, &Vec<f64>)> {
        let mut out = Vec::new();
        if self.header.mean {
            out.push(("mean".to_string(), &self.mean));
        }
        for (i, c) in self.components.iter().enumerate() {
            out.push((format!("pc{:02}", i + 1), c));
        }
        for (name, a) in self.header.materials.iter().zip(&self.atoms) {
            out.push((atom_layer(name), a));
        }
        out
    }

    /// The measured materials the hybrid model mixes: each training material's name and
    /// table. Empty for a basis file written without them.
    pub fn atoms(&self) -> impl Iterator<Item = (&str, &[f64])> {
        self.header
            .materials
            .iter()
            .map(String::as_str)
            .zip(self.atoms.iter().map(Vec::as_slice))
    }

    fn exr_bytes(&self) -> Result<Vec<u8>> {
        use exr::prelude::*;
        let size = Vec2(N_THETA_D, N_THETA_H);
        let layers: Vec<Layer<AnyChannels<FlatSamples>>> = self
            .layers()
            .into_iter()
            .map(|(name, v)| {
                // A measured material's table is data, not a model vector: half precision
                // (0.05%) halves the file, where its range allows.
                let half = name.starts_with("atom.")
                    && v.iter().all(|x| x.abs() < f64::from(f16::MAX.to_f32()));
                let channel = |label: &str, c: usize| {
                    let plane = &v[c * GRID_CELLS..(c + 1) * GRID_CELLS];
                    AnyChannel::new(
                        label,
                        if half {
                            FlatSamples::F16(plane.iter().map(|x| f16::from_f64(*x)).collect())
                        } else {
                            FlatSamples::F32(plane.iter().map(|x| *x as f32).collect())
                        },
                    )
                };
                Layer::new(
                    size,
                    LayerAttributes {
                        software_name: Some(Text::from(
                            format!("brdfd {}", env!("CARGO_PKG_VERSION")).as_str(),
                        )),
                        ..LayerAttributes::named(name.as_str())
                    },
                    Encoding::SMALL_LOSSLESS,
                    AnyChannels::sort(smallvec::smallvec![
                        channel("R", 0),
                        channel("G", 1),
                        channel("B", 2)
                    ]),
                )
            })
            .collect();
        let image = Image::from_layers(
            ImageAttributes::new(IntegerBounds::from_dimensions(size)),
            layers,
        );
        let mut out = Cursor::new(Vec::new());
        image
            .write()
            .to_buffered(&mut out)
            .map_err(|e| CoreError::format("basis EXR", e.to_string()))?;
        Ok(out.into_inner())
    }

    /// Reads a basis from its two files; `path` may name either of them or the stem.
    pub fn read(path: &Path) -> Result<Basis> {
        let exr_path = path.with_extension("exr");
        let json_path = path.with_extension("json");
        let json = std::fs::read_to_string(&json_path).map_err(|e| CoreError::io(&json_path, e))?;
        let exr = std::fs::read(&exr_path).map_err(|e| CoreError::io(&exr_path, e))?;
        Self::from_parts(&json, &exr, &path.display().to_string())
    }

    pub fn from_parts(json: &str, exr_bytes: &[u8], what: &str) -> Result<Basis> {
        use exr::prelude::*;
        let header: BasisHeader = serde_json::from_str(json).map_err(|e| {
            CoreError::format(
                format!("{what} (header)"),
                format!("line {}: {e}", e.line()),
            )
        })?;
        if header.format != FORMAT {
            return Err(CoreError::format(
                what,
                format!("format {:?}, this brdfd reads {FORMAT:?}", header.format),
            ));
        }
        if header.k == 0 || header.k > MAX_K {
            return Err(CoreError::format(
                what,
                format!("K is {}; this brdfd estimates with 1 to {MAX_K}", header.k),
            ));
        }
        let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(exr_bytes), false)
            .map_err(|e| CoreError::format(format!("{what} (EXR)"), e.to_string()))?;
        super::envmap::check_exr_size(&meta, &format!("{what} (EXR)"), exr_bytes.len())?;
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .all_layers()
            .all_attributes()
            .from_buffered(Cursor::new(exr_bytes))
            .map_err(|e| CoreError::format(format!("{what} (EXR)"), e.to_string()))?;
        let mut found: std::collections::HashMap<String, Vec<f64>> = Default::default();
        for layer in &image.layer_data {
            let name = layer
                .attributes
                .layer_name
                .as_ref()
                .map(|t| t.to_string())
                .unwrap_or_default();
            if layer.size != Vec2(N_THETA_D, N_THETA_H) {
                return Err(CoreError::format(
                    what,
                    format!(
                        "part {name} is {}×{}, expected 90×90",
                        layer.size.0, layer.size.1
                    ),
                ));
            }
            let mut v = vec![0.0; VALUES];
            for (c, label) in ["R", "G", "B"].iter().enumerate() {
                let ch = layer
                    .channel_data
                    .list
                    .iter()
                    .find(|ch| ch.name.to_string() == *label)
                    .ok_or_else(|| {
                        CoreError::format(what, format!("part {name} lacks channel {label}"))
                    })?;
                for (i, x) in ch.sample_data.values_as_f32().enumerate() {
                    if !x.is_finite() {
                        return Err(CoreError::format(
                            what,
                            format!(
                                "part {name} channel {label} has a non-finite value at cell {i}"
                            ),
                        ));
                    }
                    v[c * GRID_CELLS + i] = x as f64;
                }
            }
            found.insert(name, v);
        }
        let mut take = |name: &str| {
            found
                .remove(name)
                .ok_or_else(|| CoreError::format(what, format!("the EXR has no part {name}")))
        };
        let mean = if header.mean {
            take("mean")?
        } else {
            vec![0.0; VALUES]
        };
        let components = (1..=header.k)
            .map(|i| take(&format!("pc{i:02}")))
            .collect::<std::result::Result<Vec<_>, CoreError>>()?;
        let atoms = if header.atoms {
            header
                .materials
                .iter()
                .map(|n| take(&atom_layer(n)))
                .collect::<std::result::Result<Vec<_>, CoreError>>()?
        } else {
            Vec::new()
        };
        if let Some(i) = atoms.iter().flatten().position(|v| *v < 0.0) {
            return Err(CoreError::format(
                what,
                format!(
                    "measured material {} has a negative value at cell {}",
                    header.materials[i / VALUES],
                    i % VALUES
                ),
            ));
        }
        if header.score_std.len() < header.k {
            return Err(CoreError::format(
                what,
                "score_std has fewer entries than K",
            ));
        }
        Ok(Basis {
            header,
            mean,
            components,
            atoms,
        })
    }

    /// The basis shipped inside the binary: K = 5 from the 90 training materials.
    pub fn embedded() -> Basis {
        Self::from_parts(
            include_str!("default_basis/basis.json"),
            include_bytes!("default_basis/basis.exr"),
            "embedded default basis",
        )
        .expect("the embedded basis is checked by tests")
    }
}

fn layout_text() -> String {
    "multi-part EXR beside this file, one part per vector: 'mean' (if mean) and 'pc01'..; if atoms, 'atom.<material>' per training material (its own table); each 90x90 RGB, float32 (atoms half where their range allows), rows = theta_h bins, columns = theta_d bins; values in 1/sr; f = offset + sum(c_k * b_k)".into()
}

fn atom_layer(material: &str) -> String {
    format!("atom.{material}")
}

/// Each channel's coefficients from a solution with `m` model columns: the same slice three
/// times for a joint solution (length m), the channel's third for a per-channel one (3m).
pub fn channel_coefficients(coefficients: &[f64], m: usize) -> Result<[&[f64]; 3]> {
    if coefficients.len() == m {
        Ok([coefficients; 3])
    } else if coefficients.len() == 3 * m {
        Ok([
            &coefficients[..m],
            &coefficients[m..2 * m],
            &coefficients[2 * m..],
        ])
    } else {
        Err(CoreError::Invalid(format!(
            "{} coefficients for a model of {m} columns: expected {m} (joint colour) or {} (per channel)",
            coefficients.len(),
            3 * m
        )))
    }
}
