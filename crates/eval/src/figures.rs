//! The evaluation's figures as SVG: plots with axes, ticks, labels and legends (plotters), and
//! image grids with their rows and columns named. SVG needs no fonts to write, and a browser
//! or the repository's web view shows it.

use std::fmt::Write as _;
use std::io::Cursor;

use base64::Engine as _;
use plotters::prelude::*;

use brdfd_core::error::{CoreError, Result};
use brdfd_core::raster::Raster;

/// Line colours, one per series in order (matplotlib's "tab10", which readers know).
const COLOURS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn plot_err(e: impl std::fmt::Display) -> CoreError {
    CoreError::Invalid(format!("plotting: {e}"))
}

/// The largest finite value of any series (at least 1e-6, so an axis always has a span).
fn peak(series: &[(String, Vec<Option<f64>>)]) -> f64 {
    series
        .iter()
        .flat_map(|(_, v)| v.iter().flatten())
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max)
        .max(1e-6)
}

/// How a legend entry shows its series.
enum Marker {
    Line,
    Dot,
}

/// The series' names with their colours, one per line, in a drawing area beside the plot.
fn draw_legend(
    area: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    series: &[(String, Vec<Option<f64>>)],
    marker: Marker,
) -> Result<()> {
    for (i, (name, _)) in series.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        let y = 60 + 18 * i as i32;
        match marker {
            Marker::Line => area.draw(&PathElement::new(
                vec![(4, y), (24, y)],
                colour.stroke_width(2),
            )),
            Marker::Dot => area.draw(&Circle::new((14, y), 4, colour.filled())),
        }
        .map_err(plot_err)?;
        area.draw(&Text::new(name.clone(), (30, y - 6), ("sans-serif", 12)))
            .map_err(plot_err)?;
    }
    Ok(())
}

/// The category at axis position `x` if it is a whole index, else no label (plotters may ask
/// for ticks between the categories).
fn tick_label(categories: &[String], x: f64) -> String {
    let i = x.round();
    if (x - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < categories.len() {
        categories[i as usize].clone()
    } else {
        String::new()
    }
}

/// A line plot over categories: `categories` along x, one series per `(name, values)` (a
/// value may be missing), y from 0, with title, axis labels and a legend.
pub(crate) fn category_lines(
    title: &str,
    x_label: &str,
    y_label: &str,
    categories: &[String],
    series: &[(String, Vec<Option<f64>>)],
) -> Result<String> {
    let ymax = peak(series) * 1.08;
    let n = categories.len().max(1);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (820, 440)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        // The legend beside the plot, not over its lines.
        let (plot, legend) = root.split_horizontally(620);
        draw_legend(&legend, series, Marker::Line)?;
        let mut chart = ChartBuilder::on(&plot)
            .caption(title, ("sans-serif", 17))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .right_y_label_area_size(0)
            .build_cartesian_2d(-0.3f64..(n as f64 - 0.7), 0f64..ymax)
            .map_err(plot_err)?;
        let cats = categories.to_vec();
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .x_labels(n)
            .x_label_formatter(&move |x| tick_label(&cats, *x))
            .y_label_formatter(&|y| format!("{y:.2}"))
            .light_line_style(TRANSPARENT)
            .bold_line_style(BLACK.mix(0.08))
            .draw()
            .map_err(plot_err)?;
        for (i, (_, values)) in series.iter().enumerate() {
            let colour = COLOURS[i % COLOURS.len()];
            let points: Vec<(f64, f64)> = values
                .iter()
                .enumerate()
                .filter_map(|(x, v)| v.filter(|v| v.is_finite()).map(|v| (x as f64, v)))
                .collect();
            chart
                .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))
                .map_err(plot_err)?;
            chart
                .draw_series(points.iter().map(|p| Circle::new(*p, 3, colour.filled())))
                .map_err(plot_err)?;
        }
        root.present().map_err(plot_err)?;
    }
    Ok(svg)
}

/// A dot plot of unordered categories (materials), one row each, read across: x is the value
/// from 0, one marker per series (`(name, values)`, a value may be missing), with title, axis
/// label and a legend. Lines would join materials that have no order; rows keep names legible.
pub(crate) fn category_dots(
    title: &str,
    x_label: &str,
    categories: &[String],
    series: &[(String, Vec<Option<f64>>)],
) -> Result<String> {
    let xmax = peak(series) * 1.05;
    let n = categories.len().max(1);
    let longest = categories
        .iter()
        .map(|c| c.chars().count())
        .max()
        .unwrap_or(1) as u32;
    let height = 90 + 22 * n as u32;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (860, height)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let (plot, legend) = root.split_horizontally(700);
        draw_legend(&legend, series, Marker::Dot)?;
        // Row r of the plot is category r, the first at the top.
        let mut chart = ChartBuilder::on(&plot)
            .caption(title, ("sans-serif", 17))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(20 + 7 * longest)
            .build_cartesian_2d(0f64..xmax, -0.5f64..(n as f64 - 0.5))
            .map_err(plot_err)?;
        let cats = categories.to_vec();
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_labels(n)
            .y_label_formatter(&move |y| {
                // Row r from the bottom is category n − 1 − r.
                let flipped = (cats.len() as f64 - 1.0) - y;
                tick_label(&cats, flipped)
            })
            .x_label_formatter(&|x| format!("{x:.2}"))
            .light_line_style(TRANSPARENT)
            .bold_line_style(BLACK.mix(0.08))
            .draw()
            .map_err(plot_err)?;
        let k = series.len().max(1) as f64;
        for (i, (_, values)) in series.iter().enumerate() {
            let colour = COLOURS[i % COLOURS.len()];
            // Series side by side within a row, so that equal values stay visible.
            let offset = 0.6 * ((i as f64 + 0.5) / k - 0.5);
            let points: Vec<(f64, f64)> = values
                .iter()
                .enumerate()
                .filter_map(|(r, v)| {
                    v.filter(|v| v.is_finite())
                        .map(|v| (v, (n - 1 - r) as f64 + offset))
                })
                .collect();
            chart
                .draw_series(points.iter().map(|p| Circle::new(*p, 3, colour.filled())))
                .map_err(plot_err)?;
        }
        root.present().map_err(plot_err)?;
    }
    Ok(svg)
}

/// A grid of images: one row per `(name, images)`, columns headed `columns`, each row
/// tone-mapped with its first image's exposure; the images inline as PNGs.
pub(crate) fn image_grid(
    title: &str,
    columns: &[&str],
    rows: &[(String, Vec<Raster>)],
) -> Result<String> {
    let Some((tw, th)) = rows
        .first()
        .and_then(|(_, r)| r.first())
        .map(|r| (r.width, r.height))
    else {
        return Ok(String::new());
    };
    if let Some((name, _)) = rows
        .iter()
        .find(|(_, r)| r.is_empty() || r.iter().any(|i| (i.width, i.height) != (tw, th)))
    {
        return Err(CoreError::Invalid(format!(
            "figure row {name}: every row needs images of one size"
        )));
    }
    let (left, top, gap) = (170usize, 56usize, 4usize);
    let width = left + columns.len() * (tw + gap);
    let height = top + rows.len() * (th + gap);
    let mut svg = String::new();
    let _ = writeln!(
        svg,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width}\" height=\"{height}\" \
         viewBox=\"0 0 {width} {height}\" font-family=\"sans-serif\">\n\
         <rect width=\"{width}\" height=\"{height}\" fill=\"white\"/>\n\
         <text x=\"{}\" y=\"20\" font-size=\"16\" text-anchor=\"middle\">{}</text>",
        width / 2,
        escape(title)
    );
    for (c, name) in columns.iter().enumerate() {
        let _ = writeln!(
            svg,
            "<text x=\"{}\" y=\"{}\" font-size=\"13\" text-anchor=\"middle\">{}</text>",
            left + c * (tw + gap) + tw / 2,
            top - 10,
            escape(name)
        );
    }
    for (r, (name, images)) in rows.iter().enumerate() {
        let y = top + r * (th + gap);
        let _ = writeln!(
            svg,
            "<text x=\"{}\" y=\"{}\" font-size=\"12\" text-anchor=\"end\">{}</text>",
            left - 8,
            y + th / 2 + 4,
            escape(name)
        );
        let exposure = images[0].auto_exposure();
        for (c, image) in images.iter().enumerate() {
            let mut png = Vec::new();
            image
                .to_srgb8(exposure)
                .write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)
                .map_err(|e| CoreError::Invalid(format!("encoding a figure tile: {e}")))?;
            let _ = writeln!(
                svg,
                "<image x=\"{}\" y=\"{y}\" width=\"{tw}\" height=\"{th}\" \
                 href=\"data:image/png;base64,{}\"/>",
                left + c * (tw + gap),
                base64::engine::general_purpose::STANDARD.encode(png)
            );
        }
    }
    svg.push_str("</svg>\n");
    Ok(svg)
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_plot_has_its_title_axes_ticks_and_legend() {
        let svg = category_lines(
            "Fig. 5",
            "pixels used",
            "BRDF error",
            &["5".into(), "10".into(), "all".into()],
            &[
                ("alum-bronze".into(), vec![Some(0.5), None, Some(0.1)]),
                ("chrome".into(), vec![Some(0.9), Some(0.4), Some(0.2)]),
            ],
        )
        .unwrap();
        // plotters writes each text on a line of its own.
        for text in [
            "Fig. 5",
            "pixels used",
            "BRDF error",
            "alum-bronze",
            "chrome",
            "\nall\n",
            "\n5\n",
            "\n10\n",
        ] {
            assert!(svg.contains(text), "{text:?} missing");
        }
    }

    #[test]
    fn a_dot_plot_names_every_row() {
        let svg = category_dots(
            "Relighting",
            "relight error",
            &["nickel".into(), "ggx-gold-sharp".into()],
            &[("paper".into(), vec![Some(0.4), Some(0.6)])],
        )
        .unwrap();
        for text in [
            "Relighting",
            "relight error",
            "\nnickel\n",
            "\nggx-gold-sharp\n",
            "paper",
        ] {
            assert!(svg.contains(text), "{text:?} missing");
        }
        assert_eq!(
            svg.matches("<circle").count(),
            3,
            "two dots and the legend's"
        );
    }

    #[test]
    fn an_image_grid_names_its_rows_and_columns() {
        let img = Raster::black(4, 4);
        let svg = image_grid(
            "Fig. 6 <grace>",
            &["truth", "5"],
            &[("gold".into(), vec![img.clone(), img])],
        )
        .unwrap();
        assert!(svg.contains("Fig. 6 &lt;grace&gt;") && svg.contains(">truth<"));
        assert!(svg.contains(">gold<") && svg.matches("<image").count() == 2);
    }
}
