use brdfd::core::basis::*;
use brdfd::core::*;
fn main() {
    let set = nbrdf::NbrdfSet::read(std::path::Path::new(
        "../shared/data/merl-nbrdf/merl_nbrdf.json",
    ))
    .unwrap();
    let env =
        envmap::EnvMap::load(std::path::Path::new("../shared/data/envmaps/grace.hdr")).unwrap();
    let fine = env.compressed(8192, 0.0);
    let coarse = env.compressed(4096, 0.0);
    let g = geometry::PixelGeometry::rasterize(
        &geometry::Camera::eval_orthographic(64),
        &geometry::Shape::unit_sphere(),
    )
    .unwrap();
    let grid = bivariate::Grid::default();
    let train: Vec<(String, bivariate::Bivariate)> = set
        .materials
        .iter()
        .filter(|(n, _)| !eval::TEST_SET.contains(&n.as_str()))
        .map(|(n, m)| (n.clone(), bivariate::Bivariate::reduce(m, grid)))
        .collect();
    let variants = [
        (Normalisation::Rms, CellWeight::None, true),
        (Normalisation::Rms, CellWeight::SolidAngle, true),
        (Normalisation::None, CellWeight::None, true),
        (Normalisation::None, CellWeight::SolidAngle, true),
        (Normalisation::Rms, CellWeight::SolidAngle, false),
    ];
    let bases: Vec<Basis> = variants
        .iter()
        .map(|(n, w, m)| Basis::build(&train, 5, *n, *w, *m).unwrap())
        .collect();
    for name in eval::TEST_SET {
        let m = set.get(name).unwrap();
        let table = merl::MerlBrdf::tabulate(m);
        let photo = render::render_merl(&g, &fine, &table);
        let biv = bivariate::Bivariate::reduce(&table, grid);
        let floor_biv = render::render_bivariate(&g, &fine, &biv).relative_rmse(&photo);
        let floor_cmp = render::render_bivariate(&g, &coarse, &biv).relative_rmse(&photo);
        let mut line = format!("{name:22} biv {floor_biv:.3} +cmp {floor_cmp:.3} |");
        for b in &bases {
            let proj = render::render_bivariate(&g, &coarse, &b.reconstruct(&b.project(&biv)))
                .relative_rmse(&photo);
            let opts = estimate::EstimateOptions {
                pixel_count: None,
                ..Default::default()
            };
            let e = estimate::estimate(b, &g, &coarse, &photo, &opts).unwrap();
            let est = render::render_bivariate(&g, &coarse, &e.brdf(b)).relative_rmse(&photo);
            let o20 = estimate::EstimateOptions::default();
            let e20 = estimate::estimate(b, &g, &coarse, &photo, &o20).unwrap();
            let est20 = render::render_bivariate(&g, &coarse, &e20.brdf(b)).relative_rmse(&photo);
            line += &format!(" p{proj:.3} a{est:.3} t{est20:.3} |");
        }
        println!("{line}");
    }
}
