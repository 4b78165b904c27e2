//! `report.html`: one self-contained page per estimate, to read in a browser with no network.
//! It shows what the numbers alone hide: the photo beside the estimate and their difference
//! ([`crate::compare`]), the estimate on a sphere, BRDF slices against θh with the 1-σ band
//! (and the truth, from a simulator), the environment map with the lights used, and the
//! numbers with their verdicts and the session's record. Images are inline PNGs and plots
//! inline SVGs, so the file can be mailed or archived on its own.

use std::fmt::Write as _;
use std::io::Cursor;
use std::path::Path;

use base64::Engine as _;
use image::{ImageFormat, Rgb, RgbImage};
use plotters::prelude::*;

use crate::export::Export;
use crate::flags::Flag;
use crate::visibility::Visibility;
use brdfd_core::bivariate::{Bivariate, GRID_CELLS, N_THETA_D, N_THETA_H};
use brdfd_core::envmap::{uv_of, EnvMap, LightSet};
use brdfd_core::error::{CoreError, Result};
use brdfd_core::estimate::{fit_verdict, Estimate, GOOD_FIT, POOR_FIT};
use brdfd_core::merl;
use brdfd_core::raster::Raster;

/// What a report shows besides the estimate itself; every part is optional.
#[derive(Default)]
pub struct Context<'a> {
    /// The page's title: the session, or the files estimated from.
    pub title: String,
    /// The session's id (also recorded in `coefficients.json`).
    pub session: Option<String>,
    /// The first view's photo (linear).
    pub photo: Option<&'a Raster>,
    /// The environment map the estimate was lit by.
    pub env: Option<&'a EnvMap>,
    /// The map's turn (radians) for the first view: the one its lights were compressed with
    /// ([`EnvMap::compressed`]).
    pub yaw: f64,
    /// The estimate's relit error against a known truth (a simulator's).
    pub relight_error: Option<f64>,
    /// The true BRDF on the estimate's grid (a simulator's).
    pub truth: Option<&'a Bivariate>,
    /// The V4L2 fallback camera's use, when it shot any view: which views, and its noise.
    pub fallback: Option<String>,
    /// The session's record: what, when, which devices.
    pub record: Vec<(String, String)>,
    /// On a mesh, what of its light the object hides from itself in the first view.
    pub visibility: Option<&'a Visibility>,
    /// The object's mesh, placed in the world as the first view saw it: `object.gltf` shows
    /// the export on it.
    pub object: Option<&'a brdfd_core::mesh::Mesh>,
    /// The exports' maps and renders, made beforehand ([`crate::export::Prepared`]); made
    /// when the results are written if absent or made for another turn of `env`.
    pub exports: Option<&'a crate::export::Prepared>,
    /// When the part holds two materials, each estimated on its own
    /// ([`crate::materials`]): the page shows the split and links their reports.
    pub materials: Option<&'a crate::materials::Parts>,
}

/// θd of the BRDF slices, in degrees: near the retro direction, a middle angle, near grazing.
const SLICE_THETA_D: [f64; 3] = [5.0, 30.0, 60.0];
/// θh in degrees on the slices' square-root axis (0 to 90).
fn sqrt_axis(theta_h_deg: f64) -> f64 {
    (theta_h_deg.max(0.0) / 90.0).sqrt() * 90.0
}

/// Lowest value the log axis shows, as a fraction of the plotted peak.
const LOG_FLOOR: f64 = 1e-4;
const CHANNELS: [(&str, RGBColor); 3] = [
    ("R", RGBColor(200, 30, 30)),
    ("G", RGBColor(30, 150, 30)),
    ("B", RGBColor(30, 60, 210)),
];

/// What brdfd judged of the estimate beyond its fit: how its exports relight, and the
/// assumptions the photo says are broken.
pub struct Judged<'a> {
    /// The verdict in words ([`crate::summary::headline`]).
    pub headline: &'a str,
    pub export: &'a Export,
    pub flags: &'a [Flag],
}

/// Writes the report for `estimate` (with its `preview`, the estimate on a sphere, and the
/// `lights` it was fitted under) to `path`.
pub fn write(
    path: &Path,
    estimate: &Estimate,
    basis_id: &str,
    preview: &RgbImage,
    lights: &LightSet,
    judged: &Judged,
    cx: &Context,
) -> Result<()> {
    let html = page(estimate, basis_id, preview, lights, judged, cx)?;
    std::fs::write(path, html).map_err(|e| CoreError::io(path, e))
}

fn page(
    est: &Estimate,
    basis_id: &str,
    preview: &RgbImage,
    lights: &LightSet,
    judged: &Judged,
    cx: &Context,
) -> Result<String> {
    let Judged {
        headline,
        export,
        flags,
    } = *judged;
    // The page's costly parts, the relit spheres' renders and the slices' plots, made side by
    // side: the plots are serial work.
    let (relit, slices) = rayon::join(
        || relit_spheres(est),
        || {
            SLICE_THETA_D
                .map(|theta_d| slice_svg(est, cx.truth, theta_d))
                .into_iter()
                .collect::<Result<Vec<String>>>()
        },
    );
    let mut h = String::new();
    let title = escape(&cx.title);
    let _ = writeln!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <title>brdfd report: {title}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n\
         <h1>brdfd report: {title}</h1>\n<p class=\"verdict\">Verdict: {}</p>\n\
         <p class=\"summary\">{}</p>",
        escape(headline),
        escape(&est.method_text())
    );
    // A broken assumption comes before any picture: the numbers below are judged as if
    // the model held.
    for f in flags {
        let _ = writeln!(h, "<p class=\"flag\">Flagged: {}</p>", escape(&f.text));
    }
    if let Some(parts) = cx.materials {
        materials_section(&mut h, parts, est.fit_error)?;
    }

    h.push_str("<h2>Photo against estimate</h2>\n");
    match cx.photo {
        Some(photo) => {
            let mut img = crate::compare::picture(photo, &est.rerender, 0);
            let chosen: Vec<(u32, u32)> = est.outcome.basis().map_or(Vec::new(), |b| {
                b.chosen
                    .iter()
                    .zip(&b.chosen_views)
                    .filter(|(_, v)| **v == 0)
                    .map(|(p, _)| *p)
                    .collect()
            });
            crate::compare::mark(&mut img, photo, &chosen);
            let _ = writeln!(
                h,
                "<figure>{}<figcaption>Left: the photo (first view). Middle: the estimate \
                 re-rendered under the same light, at the photo's exposure{}. Right: the \
                 difference in brightness, estimate − photo; the bar below runs from blue \
                 (estimate darker by {pct}% of the photo's RMS brightness) through white \
                 (equal) to red (brighter by {pct}%). Black: not compared (background, or \
                 clipped in every frame).</figcaption></figure>",
                img_tag(&img, "photo, estimate and difference")?,
                if chosen.is_empty() {
                    String::new()
                } else {
                    format!(
                        "; green squares mark the {} pixels the solve used",
                        chosen.len()
                    )
                },
                pct = (100.0 * crate::compare::ERROR_SCALE).round(),
            );
        }
        None => h.push_str("<p>No photo was given to this report.</p>\n"),
    }

    if let Some(v) = cx.visibility {
        let _ = writeln!(
            h,
            "<figure>{}<figcaption>The light the object's own shape lets each pixel of the \
             first view see: white where it sees all the light above its surface, black where \
             the part hides it all (and off the object). On average {:.0}% of it; the estimate \
             counts only the lights each pixel sees (visibility.png).</figcaption></figure>",
            img_tag(&v.picture(), "visible fraction of the light")?,
            100.0 * v.mean,
        );
    }

    h.push_str("<h2>The estimate</h2>\n<div class=\"row\">\n");
    let _ = writeln!(
        h,
        "<figure>{}<figcaption>The estimate on a sphere, under the light it was fitted \
         to; white is the brightest point of a white matte sphere under that light \
         (preview.png).</figcaption></figure>",
        img_tag(preview, "the estimate on a sphere")?
    );
    if let Some(env) = cx.env {
        let _ = writeln!(
            h,
            "<figure>{}<figcaption>The environment map (equirectangular, tone-mapped), with \
             the {} lights the estimate was rendered with as dots.</figcaption></figure>",
            img_tag(&map_thumbnail(env, cx.yaw, lights), "environment map")?,
            lights.len()
        );
    }
    h.push_str("</div>\n");

    h.push_str("<h2>Under other light</h2>\n<div class=\"row\">\n");
    for (name, sphere) in relit? {
        let _ = writeln!(
            h,
            "<figure>{}<figcaption>Relit under brdfd's {name} map.</figcaption></figure>",
            img_tag(&sphere, &format!("the estimate under the {name} map"))?
        );
    }
    let _ = writeln!(
        h,
        "</div>\n<p class=\"note\">The estimate on a sphere under two reference maps that \
         ship with brdfd, the same for every session (the simulated bench itself uses the \
         studio map). Each is exposed so that a white matte sphere (albedo 1) under the same \
         map would reach white at its brightest: spheres of different sessions compare \
         directly.</p>"
    );

    h.push_str("<h2>BRDF slices</h2>\n<div class=\"row\">\n");
    for svg in slices? {
        h.push_str(&svg);
    }
    let _ = writeln!(
        h,
        "</div>\n<p class=\"note\">The estimate's BRDF against the half-angle θh at three \
         difference angles θd, per channel, on a log axis against √θh{}{}.</p>",
        if !est.uncertainty.band.is_empty() {
            "; the shaded band is its 1-σ uncertainty"
        } else {
            ""
        },
        if cx.truth.is_some() {
            "; dashed: the truth (the simulator's material)"
        } else {
            ""
        }
    );

    h.push_str("<h2>Numbers</h2>\n<table>\n");
    for (k, v) in numbers(est, basis_id, export, cx) {
        let _ = writeln!(h, "<tr><th>{}</th><td>{}</td></tr>", escape(&k), escape(&v));
    }
    h.push_str("</table>\n<details><summary>Coefficients</summary>\n<table>\n");
    for (n, c) in est.names.iter().zip(&est.solution.coefficients) {
        let _ = writeln!(h, "<tr><th>{}</th><td>{c:+.6}</td></tr>", escape(n));
    }
    h.push_str("</table>\n</details>\n");
    if !cx.record.is_empty() {
        h.push_str("<h2>Record</h2>\n<table>\n");
        for (k, v) in &cx.record {
            let _ = writeln!(h, "<tr><th>{}</th><td>{}</td></tr>", escape(k), escape(v));
        }
        h.push_str("</table>\n");
    }
    let _ = writeln!(
        h,
        "<p class=\"note\">Written by brdfd {}.</p>\n</body>\n</html>",
        env!("CARGO_PKG_VERSION")
    );
    Ok(h)
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;\
color:#222}h1{font-size:1.4em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ccc}\
figure{margin:0.5em 1em 0.5em 0;display:inline-block;vertical-align:top;max-width:100%}\
figure img{max-width:100%;height:auto;image-rendering:pixelated}figcaption{font-size:0.85em;color:#555;\
max-width:780px}.row{display:flex;flex-wrap:wrap;gap:0.5em}table{border-collapse:collapse}\
th,td{text-align:left;padding:0.2em 0.8em;border-bottom:1px solid #eee;vertical-align:top}\
th{font-weight:normal;color:#555}.verdict{font-size:1.2em;font-weight:bold}.summary{font-size:1.05em}.flag{border-left:4px solid #c60;padding-left:0.6em}.note{font-size:0.85em;color:#555}";

/// The numbers, each with its verdict where brdfd has one.
fn numbers(est: &Estimate, basis_id: &str, export: &Export, cx: &Context) -> Vec<(String, String)> {
    let mut rows = vec![
        (
            "model".to_string(),
            match est.chosen_lobe() {
                Some(l) => {
                    let ((smooth, rough), model) = (l.smooth_and_rough(), est.model().name());
                    format!(
                        "an anisotropic GGX lobe (α {smooth:.3} and {rough:.3}), chosen over the {model} model: what the estimate relights with (brdf-anisotropic.binary); the BRDF slices and brdf.binary are the {model} model's, isotropic"
                    )
                }
                None => est.model().name().to_string(),
            },
        ),
        (
            "fit to the photo".to_string(),
            format!(
                "{:.4} relative RMSE over {} pixels ({})",
                est.fit_error,
                est.candidates,
                fit_verdict(est.fit_error)
            ),
        ),
    ];
    if let Some(e) = cx.relight_error {
        rows.push((
            "relit under light it was not fitted to".into(),
            format!(
                "{e:.4} relative RMSE against the truth ({}: a simulation's figure, judged as the fit, good at most {GOOD_FIT} and poor above {POOR_FIT})",
                crate::summary::relight_grade(e).word()
            ),
        ));
    }
    // The conditioning and the bootstrap are the model's, when a lobe relights instead.
    let of_model = if est.chosen_lobe().is_some() {
        " (the isotropic model's)"
    } else {
        ""
    };
    rows.push((
        format!("condition number{of_model}"),
        match crate::summary::condition_judged(est.condition()) {
            Some((_, words)) => format!("{} ({words})", est.condition_text()),
            None => est.condition_text(),
        },
    ));
    rows.push((
        "material.gltf".into(),
        format!(
            "relit {:.4} from the estimate under light its fit did not see ({})",
            export.relight_error, export.verdict
        ),
    ));
    rows.push((
        "material.mtlx (OpenPBR)".into(),
        match (export.mtlx_relight_error, &export.mtlx_verdict) {
            (Some(e), Some(v)) => format!(
                "relit {e:.4} from the estimate under the same light, rendered with OpenPBR's BRDF ({v})"
            ),
            _ => "not measured: OpenPBR's BRDF in brdfd holds no anisotropic lobe".into(),
        },
    ));
    rows.push((format!("steadiness{of_model}"), est.certainty_text().0));
    rows.push((
        "clipped pixels".into(),
        if est.clipped == 0 {
            "none".into()
        } else {
            format!(
                "{} (clipped in every frame of their bracket, left out)",
                est.clipped
            )
        },
    ));
    rows.push(("lights".into(), est.lights.to_string()));
    rows.push(("basis".into(), basis_id.to_string()));
    // The parts the model had: the hybrid and analytic fits spend it all in their solve.
    let t = &est.timings;
    let parts: Vec<String> = [
        ("rendering matrix", t.rendering_matrix_s),
        ("pixel selection", t.selection_s),
        ("chosen rows", t.chosen_rows_s),
        ("solve", t.solve_s),
    ]
    .iter()
    .filter(|(_, s)| *s > 0.0)
    .map(|(name, s)| format!("{name} {s:.3} s"))
    .collect();
    rows.push(("timings".into(), parts.join(", ")));
    rows
}

/// One BRDF slice at the θd bin nearest `theta_d_deg`, as an inline SVG plot.
fn slice_svg(est: &Estimate, truth: Option<&Bivariate>, theta_d_deg: f64) -> Result<String> {
    let brdf = &est.brdf;
    let jd = (0..N_THETA_D)
        .min_by(|&a, &b| {
            let d = |j: usize| (merl::theta_d_center(j).to_degrees() - theta_d_deg).abs();
            d(a).total_cmp(&d(b))
        })
        .expect("θd bins");
    let band = Some(est.uncertainty.band.as_slice()).filter(|b| b.len() == brdf.values.len());
    let cells: Vec<(f64, usize)> = (0..N_THETA_H)
        .map(|ih| (ih, ih * N_THETA_D + jd))
        .filter(|&(_, g)| brdf.valid[g])
        // x is √θh scaled to 0–90, MERL's own θh axis: a sharp peak spreads over the plot
        // instead of sitting within θh < 5° of a linear one.
        .map(|(ih, g)| {
            (
                sqrt_axis(brdf.grid.theta_h_binning.center(ih).to_degrees()),
                g,
            )
        })
        .collect();
    let value = |b: &Bivariate, c: usize, g: usize| b.values[c * GRID_CELLS + g];
    let peak = cells
        .iter()
        .flat_map(|&(_, g)| {
            (0..3).flat_map(move |c| {
                let mut v = vec![value(brdf, c, g)];
                if let Some(t) = truth {
                    v.push(value(t, c, g));
                }
                v
            })
        })
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max)
        .max(1e-12);
    let floor = peak * LOG_FLOOR;
    let top = peak * 2.0;
    let clamp = |v: f64| {
        if v.is_finite() {
            v.clamp(floor, top)
        } else {
            floor
        }
    };

    let mut svg = String::new();
    let plot_err = |e: &dyn std::fmt::Display| CoreError::Invalid(format!("plotting: {e}"));
    {
        let root = SVGBackend::with_string(&mut svg, (360, 280)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err(&e))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("θd = {:.1}°", merl::theta_d_center(jd).to_degrees()),
                ("sans-serif", 15),
            )
            .margin(8)
            .x_label_area_size(36)
            .y_label_area_size(58)
            .build_cartesian_2d(0f64..90f64, (floor..top).log_scale())
            .map_err(|e| plot_err(&e))?;
        chart
            .configure_mesh()
            .x_desc("θh (degrees, square-root scale)")
            .y_desc("BRDF (1/sr)")
            .x_labels(10)
            .x_label_formatter(&|v| {
                let theta = (v / 90.0).powi(2) * 90.0;
                if theta < 10.0 {
                    format!("{theta:.1}")
                } else {
                    format!("{theta:.0}")
                }
            })
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .light_line_style(TRANSPARENT)
            .bold_line_style(BLACK.mix(0.08))
            .draw()
            .map_err(|e| plot_err(&e))?;
        for (c, (name, colour)) in CHANNELS.iter().enumerate() {
            if let Some(band) = band {
                let upper: Vec<(f64, f64)> = cells
                    .iter()
                    .map(|&(x, g)| (x, clamp(value(brdf, c, g) + band[c * GRID_CELLS + g])))
                    .collect();
                let lower: Vec<(f64, f64)> = cells
                    .iter()
                    .rev()
                    .map(|&(x, g)| (x, clamp(value(brdf, c, g) - band[c * GRID_CELLS + g])))
                    .collect();
                chart
                    .draw_series(std::iter::once(Polygon::new(
                        [upper, lower].concat(),
                        colour.mix(0.15).filled(),
                    )))
                    .map_err(|e| plot_err(&e))?;
            }
            chart
                .draw_series(LineSeries::new(
                    cells.iter().map(|&(x, g)| (x, clamp(value(brdf, c, g)))),
                    colour.stroke_width(2),
                ))
                .map_err(|e| plot_err(&e))?
                .label(format!("estimate {name}"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour));
            if let Some(t) = truth {
                let drawn = chart
                    .draw_series(DashedLineSeries::new(
                        cells.iter().map(|&(x, g)| (x, clamp(value(t, c, g)))),
                        5,
                        4,
                        colour.stroke_width(1),
                    ))
                    .map_err(|e| plot_err(&e))?;
                if c == 0 {
                    drawn.label("truth (dashed)").legend(|(x, y)| {
                        PathElement::new(vec![(x, y), (x + 6, y)], BLACK.stroke_width(1))
                    });
                }
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK.mix(0.3))
            .draw()
            .map_err(|e| plot_err(&e))?;
        root.present().map_err(|e| plot_err(&e))?;
    }
    Ok(svg)
}

/// Pixels on a side of the relit spheres, and lights they are rendered with: enough for a
/// picture, a few hundredths of a second each.
const RELIT_SIZE: usize = 128;
const RELIT_LIGHTS: usize = 512;

/// The estimate on a sphere under each of [`crate::lights::reference_maps`], each on the fixed
/// scale of a white Lambertian sphere under the same map.
fn relit_spheres(est: &Estimate) -> Result<Vec<(&'static str, RgbImage)>> {
    crate::lights::reference_maps()
        .into_iter()
        .map(|(name, map)| {
            let lights = map.compressed(RELIT_LIGHTS, 0.0);
            Ok((name, est.sphere_picture(&lights, RELIT_SIZE)?.to_srgb8()))
        })
        .collect()
}

/// The environment map, tone-mapped and at most 512 pixels wide, with the lights as dots.
fn map_thumbnail(env: &EnvMap, yaw: f64, lights: &LightSet) -> RgbImage {
    let step = env.width.div_ceil(512).max(1);
    let (w, h) = (env.width.div_ceil(step), env.height.div_ceil(step));
    let mut small = Raster::black(w, h);
    let mut count = vec![0u32; w * h];
    for y in 0..env.height {
        for x in 0..env.width {
            let i = (y / step) * w + x / step;
            let p = env.pixels[y * env.width + x];
            for c in 0..3 {
                small.pixels[i][c] += p[c];
            }
            count[i] += 1;
        }
    }
    for (p, n) in small.pixels.iter_mut().zip(&count) {
        *p = p.map(|v| v / (*n).max(1) as f32);
    }
    let mut img = small.to_srgb8(small.auto_exposure());
    for d in &lights.directions {
        // The lights were turned by `yaw` with the map: turn them back onto it.
        let (u, v) = uv_of([d[0] as f64, d[1] as f64, d[2] as f64]);
        let u = (u + yaw / std::f64::consts::TAU).rem_euclid(1.0);
        let (x, y) = ((u * w as f64) as u32, (v * h as f64) as u32);
        if x < w as u32 && y < h as u32 {
            img.put_pixel(x, y, Rgb([0, 220, 255]));
        }
    }
    img
}

/// The part's two materials: the split on the photo, and each material's figures and report.
fn materials_section(h: &mut String, parts: &crate::materials::Parts, whole: f64) -> Result<()> {
    let r = &parts.record;
    let _ = writeln!(
        h,
        "<h2>Materials</h2>\n<p>The part holds {} materials: the photo's colour departs from \
         one BRDF's by {:.2} from place to place (RMS of ln colour shares; split from {}), so \
         each material was estimated on its own pixels. Together they re-render the photo to \
         {:.4}, against {:.4} for the one BRDF this page describes below.</p>",
        r.parts.len(),
        r.departure,
        brdfd_core::materials::DEPARTS_FROM,
        r.fit_error,
        whole,
    );
    if let Some(picture) = &parts.picture {
        let _ = writeln!(
            h,
            "<figure>{}<figcaption>The first view's pixels by material: orange the first, \
             cyan the second (materials.png; materials-mask.png holds the labels, 1 and 2, \
             0 off the part).</figcaption></figure>",
            img_tag(picture, "the part's pixels by material")?
        );
    }
    h.push_str("<table>\n<tr><th>material</th><th>colour</th><th>pixels</th><th>fit</th><th>report</th></tr>\n");
    for p in &r.parts {
        let swatch = p
            .colour
            .map(|c| (brdfd_core::raster::linear_to_srgb(c as f32) * 255.0).round() as u8);
        let _ = writeln!(
            h,
            "<tr><td>{folder}</td><td><span style=\"display:inline-block;width:2em;height:1em;\
             background:rgb({},{},{})\"></span></td><td>{} ({:.0}%)</td><td>{:.4} ({})</td>\
             <td><a href=\"{folder}/report.html\">{folder}/report.html</a></td></tr>",
            swatch[0],
            swatch[1],
            swatch[2],
            p.pixels,
            100.0 * p.share,
            p.fit_error,
            fit_verdict(p.fit_error),
            folder = escape(&p.folder),
        );
    }
    h.push_str("</table>\n");
    Ok(())
}

/// An `<img>` with the image inline as a PNG data URI.
fn img_tag(img: &RgbImage, alt: &str) -> Result<String> {
    let mut png = Vec::new();
    img.write_to(&mut Cursor::new(&mut png), ImageFormat::Png)
        .map_err(|e| CoreError::Invalid(format!("encoding a PNG for the report: {e}")))?;
    Ok(format!(
        "<img alt=\"{}\" width=\"{}\" height=\"{}\" src=\"data:image/png;base64,{}\">",
        escape(alt),
        img.width(),
        img.height(),
        base64::engine::general_purpose::STANDARD.encode(png)
    ))
}

/// Text made safe for HTML content and attribute values.
fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for ch in s.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_from_a_session_cannot_open_a_tag() {
        assert_eq!(
            escape("<script>alert('x')</script> & \"q\""),
            "&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt; &amp; &quot;q&quot;"
        );
    }
}
