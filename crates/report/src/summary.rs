//! The result in a few judged lines, answer first: what `brdfd capture` and `brdfd estimate`
//! print when an estimate is done.
//!
//! Every number printed comes with its verdict and the threshold it was judged by, and the
//! first line is the worst of them: a poor or unsteady estimate never opens with "good". The
//! coefficients themselves are in `coefficients.json` (and printed with `--verbose`): they are
//! a model's internals, not what the material is.
//!
//! Not here: the thresholds of the fit and the steadiness ([`brdfd_core::estimate`]) and of
//! the exports ([`crate::export`]); this module only gathers them.

use std::path::Path;

use crate::export::{export_word, Export, CLOSE, FAITHFUL};
use crate::flags::Flag;
use brdfd_core::estimate::{
    fit_bounds, fit_verdict, Estimate, Model, GOOD_FIT, POOR_FIT, UNSTEADY_SPREAD,
};

/// Condition numbers at or below this are good: the presets' estimates on the sphere measure
/// about 300 (276–351 at 256²), and the hybrid's many columns can make a few thousand usual.
pub const WELL_CONDITIONED: f64 = 1e4;
/// Above this a system is ill-conditioned: noise in the photo is amplified more than
/// 100,000-fold in the direction the pixels pin worst. More views, or pixels facing more
/// directions, pin it better (the gold part's mesh from one view measures 16,000: fair).
pub const ILL_CONDITIONED: f64 = 1e5;

/// How a number was judged, from best to worst; an estimate's verdict is the worst of its
/// numbers' ([`grade`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Grade {
    Good,
    Fair,
    Poor,
}

impl Grade {
    pub fn word(self) -> &'static str {
        match self {
            Grade::Good => "good",
            Grade::Fair => "fair",
            Grade::Poor => "poor",
        }
    }

    /// Against two thresholds, lower being better; not a number is poor.
    fn of(value: f64, good: f64, poor: f64) -> Grade {
        if value <= good {
            Grade::Good
        } else if value <= poor {
            Grade::Fair
        } else {
            Grade::Poor
        }
    }
}

/// One judged line.
struct Line {
    grade: Grade,
    text: String,
}

/// What the summary knows beside the estimate.
pub struct Extras<'a> {
    /// The verdict in words as the written results hold it (`ResultFiles::headline`, worked
    /// out by [`grade`] or [`parts_grade`] where they were written): the summary opens with
    /// it, so that it says what `coefficients.json`, the report and the web page say.
    pub headline: &'a str,
    /// A simulated capture's relit error against the truth, and the light it was relit
    /// under.
    pub relight: Option<(f64, String)>,
    /// How many views (photos) the estimate was fitted to.
    pub views: usize,
    /// Whether the photos were merged from exposure brackets (a capture's are).
    pub bracketed: bool,
    pub export: Option<&'a Export>,
    /// The assumptions of the model the photo says are broken ([`crate::flags`]).
    pub flags: &'a [Flag],
    pub report: Option<&'a Path>,
    /// When the part holds two materials: what was written of them, and their estimates
    /// (in the order of the record's parts).
    pub materials: Option<(&'a crate::materials::Parts, &'a [Estimate])>,
}

/// The judged lines of an estimate fitted to `views` photos, with a simulation's relit error
/// and the light it was relit under, and the broken assumptions its photo shows.
fn judged(
    estimate: &Estimate,
    relight: Option<(f64, &str)>,
    flags: &[Flag],
    views: usize,
) -> Vec<Line> {
    let mut lines = Vec::new();
    // The fit of what the estimate relights with: the anisotropic lobe's, when it chose one.
    let fit = estimate.fit_error;
    lines.push(Line {
        grade: Grade::of(fit, GOOD_FIT, POOR_FIT),
        text: format!(
            "re-renders the photo{} to a relative RMSE of {fit:.4} over {} pixels ({})",
            if views > 1 { "s" } else { "" },
            estimate.candidates,
            fit_bounds(fit)
        ),
    });
    if let Some((e, under)) = relight {
        lines.push(Line {
            grade: relight_grade(e),
            text: format!(
                "relit under {under} (light it was not fitted to), the estimate is {e:.4} from the truth (a simulation's figure, judged as the fit)"
            ),
        });
    }
    // The bootstrap and the conditioning are the model's: said so when a lobe relights.
    let of_model = if estimate.chosen_lobe().is_some() {
        "its isotropic model: "
    } else {
        ""
    };
    {
        let u = &estimate.uncertainty;
        let s = u.bootstrap_spread;
        let (grade, word) = if s <= UNSTEADY_SPREAD {
            (Grade::Good, "steady: at most")
        } else {
            (Grade::Poor, "unsteady: above")
        };
        lines.push(Line {
            grade,
            text: format!(
                "{of_model}resampling its pixels {} times moves its relit sphere by {:.1}% RMS ({word} {:.0}%)",
                u.resamples,
                100.0 * s,
                100.0 * UNSTEADY_SPREAD
            ),
        });
    }
    // A broken assumption makes the figures above optimistic: fair at best, whatever they say.
    lines.extend(flags.iter().map(|f| Line {
        grade: Grade::Fair,
        text: f.text.clone(),
    }));
    if let Some((grade, words)) = condition_judged(estimate.condition()) {
        lines.push(Line {
            grade,
            text: format!(
                "{of_model}condition number {:.0} ({words})",
                estimate.condition()
            ),
        });
    }
    lines
}

/// A simulation's relit error against the truth, judged as the fit is.
pub fn relight_grade(e: f64) -> Grade {
    Grade::of(e, GOOD_FIT, POOR_FIT)
}

/// A condition number's grade and words, or `None` for an infinite one: the prior solves a
/// system with fewer equations than unknowns, whose κ is infinite by construction and says
/// nothing of noise, so it is reported, not judged.
pub fn condition_judged(k: f64) -> Option<(Grade, String)> {
    if !k.is_finite() {
        return None;
    }
    let grade = Grade::of(k, WELL_CONDITIONED, ILL_CONDITIONED);
    let words = match grade {
        Grade::Good => format!("well conditioned: at most {WELL_CONDITIONED:.0}"),
        Grade::Fair => format!("noise is amplified: above {WELL_CONDITIONED:.0}"),
        Grade::Poor => format!(
            "ill-conditioned: above {ILL_CONDITIONED:.0}; more views or pixels facing more ways pin it better"
        ),
    };
    Some((grade, words))
}

/// The verdict on one estimate: the worst of its judged numbers (the fit, a simulation's
/// relit error against the truth, the steadiness, the conditioning) and of the broken
/// assumptions its photo shows, each of which makes it fair at best: the worst of the lines
/// [`lines`] prints. Worked out where the results are written, which keep it; the summary
/// opens with what they kept ([`Extras::headline`]).
pub fn grade(estimate: &Estimate, relight: Option<f64>, flags: &[Flag]) -> Grade {
    let judged = judged(estimate, relight.map(|e| (e, "")), flags, 1);
    judged.iter().map(|l| l.grade).max().unwrap_or(Grade::Poor)
}

/// The verdict on a part split into materials: the worst material's ([`grade`] of each on
/// its own), fair at best when the whole part's photo shows a broken assumption beside its
/// colours, and no better than a simulation's relit error of the whole part.
pub fn parts_grade(parts: &[Grade], whole_flags: &[Flag], relight: Option<f64>) -> Grade {
    let mut worst = parts.iter().copied().fold(Grade::Good, Grade::max);
    if whole_flags
        .iter()
        .any(|f| f.reason != crate::flags::Reason::SeveralMaterials)
    {
        worst = worst.max(Grade::Fair);
    }
    match relight {
        Some(e) => worst.max(relight_grade(e)),
        None => worst,
    }
}

/// The verdict in words, as the summary's first line and the report's top give it: e.g.
/// "good estimate (hybrid model)", with what to do when it is not good.
pub fn headline(estimate: &Estimate, grade: Grade) -> String {
    let model = match estimate.model() {
        Model::Hybrid => "hybrid model",
        Model::Analytic => "analytic model",
        Model::Basis => "basis model",
    };
    let model = match estimate.chosen_lobe() {
        Some(_) => format!("an anisotropic GGX lobe, chosen over the {model}"),
        None => model.to_string(),
    };
    format!(
        "{} estimate ({model}){}",
        grade.word(),
        match grade {
            Grade::Good => "",
            Grade::Fair => "; look at the report before relying on it",
            Grade::Poor => "; do not trust it under other light",
        }
    )
}

/// [`headline`] for a part split into `parts` materials.
pub fn parts_headline(parts: usize, grade: Grade) -> String {
    format!(
        "{parts} materials, {} estimates{}",
        grade.word(),
        match grade {
            Grade::Good => "",
            Grade::Fair => "; look at the reports before relying on them",
            Grade::Poor => "; do not trust them under other light",
        }
    )
}

/// The summary's lines: the verdict first, then each judged number, the exports and where the
/// report is.
pub fn lines(material: &str, estimate: &Estimate, extras: &Extras) -> Vec<String> {
    if let Some((parts, estimates)) = extras.materials {
        return materials_lines(material, estimate, extras, parts, estimates);
    }
    let relight = extras
        .relight
        .as_ref()
        .map(|(e, under)| (*e, under.as_str()));
    let judged = judged(estimate, relight, extras.flags, extras.views);
    let mut out = vec![format!("{material}: {}", extras.headline)];
    out.extend(
        judged
            .iter()
            .map(|l| format!("  {}: {}", l.grade.word(), l.text)),
    );
    if let Some(b) = &estimate.bounce {
        out.push(format!(
            "  the part lights itself: {:.1}% of the light its pixels measured is light its own surface threw on them (up to two bounces through the estimate, on {} pixels), taken out before the fit; fitted with it left in, the fit was {:.4} (--no-bounce)",
            100.0 * b.share,
            b.pixels,
            b.fit_without
        ));
    }
    out.extend(clipped_line(estimate, extras));
    if let Some(e) = extras.export {
        out.push(format!("  {}", exports_text("", e)));
        if e.relight_error > CLOSE {
            out.push(
                "    the glTF/OpenPBR model cannot hold this material; brdf.binary (MERL) keeps it whole"
                    .into(),
            );
        } else if e.mtlx_relight_error.is_some_and(|m| m > CLOSE) {
            out.push(
                "    OpenPBR, as brdfd reads the fit into it, does not hold this material as glTF does; material.gltf and brdf.binary (MERL) keep it closer"
                    .into(),
            );
        }
    }
    if let Some(r) = extras.report {
        out.push(format!("  report: {}", r.display()));
    }
    out
}

/// The exports' line: each file in `folder` (empty, or a material's folder and a slash), how
/// far it relights from the estimate under light its fit did not see, and the words for it.
fn exports_text(folder: &str, e: &Export) -> String {
    let mtlx = match e.mtlx_relight_error {
        Some(m) => format!("{m:.3}, {}", export_word(m)),
        None => "not measured (an anisotropic lobe)".into(),
    };
    format!(
        "{folder}material.gltf relit {:.3} from the estimate, {}; {folder}material.mtlx (OpenPBR) {mtlx} (faithful at most {FAITHFUL}, close at most {CLOSE})",
        e.relight_error,
        export_word(e.relight_error),
    )
}

/// The summary of a part split into materials: the verdict of the worst material first, then
/// the split, then each material's judged lines and exports, then the one BRDF fitted to the
/// whole part, for comparison.
fn materials_lines(
    material: &str,
    whole: &Estimate,
    extras: &Extras,
    parts: &crate::materials::Parts,
    estimates: &[Estimate],
) -> Vec<String> {
    let r = &parts.record;
    let mut body = Vec::new();
    for ((p, files), estimate) in r.parts.iter().zip(&parts.files).zip(estimates) {
        let judged = judged(estimate, None, &files.flags, extras.views);
        body.push(format!(
            "  {} ({:.0}% of the pixels; its results in {}/):",
            p.folder.replace('-', " "),
            100.0 * p.share,
            p.folder
        ));
        body.extend(
            judged
                .iter()
                .map(|l| format!("    {}: {}", l.grade.word(), l.text)),
        );
        if let Some(b) = &estimate.bounce {
            body.push(format!(
                "    it lights itself: {:.1}% of the light its pixels measured, taken out before the fit",
                100.0 * b.share
            ));
        }
        body.push(format!(
            "    {}",
            exports_text(&format!("{}/", p.folder), &files.exports)
        ));
    }
    // What the whole part's photo says beside its colours (the light turned, the part
    // lighting itself) holds for both materials, and judges them too.
    let whole_flags: Vec<&Flag> = extras
        .flags
        .iter()
        .filter(|f| f.reason != crate::flags::Reason::SeveralMaterials)
        .collect();
    let relight = extras.relight.as_ref().map(|(e, under)| {
        format!(
            "  {}: relit under {under} (light it was not fitted to), the whole part's estimate is {e:.4} from the truth (a simulation's figure, judged as the fit)",
            relight_grade(*e).word()
        )
    });
    let mut out = vec![format!("{material}: {}", extras.headline)];
    out.push(format!(
        "  the photo's colour departs from one BRDF's by {:.2} from place to place (split from {}): each material was estimated on its own pixels, and together they re-render the photo to {:.4} ({})",
        r.departure,
        brdfd_core::materials::DEPARTS_FROM,
        r.fit_error,
        fit_verdict(r.fit_error)
    ));
    out.extend(body);
    out.push(format!(
        "  one BRDF for the whole part (coefficients.json, material.gltf) re-renders it to {:.4} ({}); object.gltf carries both materials on the mesh where there is one",
        whole.fit_error,
        fit_verdict(whole.fit_error)
    ));
    out.extend(relight);
    out.extend(whole_flags.iter().map(|f| format!("  fair: {}", f.text)));
    out.extend(clipped_line(whole, extras));
    if let Some(r) = extras.report {
        out.push(format!("  report: {}", r.display()));
    }
    out
}

/// The object pixels left out as clipped, when there are any.
fn clipped_line(estimate: &Estimate, extras: &Extras) -> Option<String> {
    (estimate.clipped > 0).then(|| {
        if extras.bracketed {
            format!(
                "  {} object pixels were clipped in every frame of their bracket and left out; a shorter exposure would keep them",
                estimate.clipped
            )
        } else {
            format!(
                "  {} object pixels were clipped (at or above the white level) and left out",
                estimate.clipped
            )
        }
    })
}
