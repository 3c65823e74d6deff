//! The report's figures, as the paper draws them: successes per task and condition (bars),
//! completion percentages (violins with the mean), Likert medians per item (a radar, a star
//! where a condition differs from the reference after Holm), NASA-TLX subscales (violins
//! with the median). Each as PNG and SVG through [`learning::experiments::figure`].

use std::path::{Path, PathBuf};

use learning::experiments::figure::{self, COLOURS, Figure};
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::StudyError;
use crate::report::{Report, Tested, mean, median};

/// Writes every figure of `r` into `out`; returns the files.
pub fn write_all(r: &Report, out: &Path) -> Result<Vec<PathBuf>, StudyError> {
    let mut files = Vec::new();
    let mut put = |fig: &dyn DynFigure, stem: &str, size: (u32, u32)| -> Result<(), StudyError> {
        let path = out.join(stem);
        fig.write(&path, size)?;
        files.push(path.with_extension("png"));
        files.push(path.with_extension("svg"));
        Ok(())
    };
    put(&Bars { r }, "successes", (900, 500))?;
    let completion: Vec<&Tested> = r
        .measures
        .iter()
        .filter(|m| m.kind == "completion")
        .collect();
    if !completion.is_empty() {
        put(
            &Violins {
                r,
                panels: completion,
                y: (0.0, 100.0),
                mark_mean: true,
            },
            "completion",
            (900, 500),
        )?;
    }
    for task in &r.tasks {
        let likert: Vec<&Tested> = r
            .measures
            .iter()
            .filter(|m| &m.task == task && m.kind == "likert")
            .collect();
        if !likert.is_empty() {
            put(
                &Radar { r, items: likert },
                &format!("likert-{task}"),
                (700, 700),
            )?;
        }
        let tlx: Vec<&Tested> = r
            .measures
            .iter()
            .filter(|m| &m.task == task && m.kind == "tlx")
            .collect();
        if !tlx.is_empty() {
            put(
                &Violins {
                    r,
                    panels: tlx,
                    y: (0.0, 100.0),
                    mark_mean: false,
                },
                &format!("tlx-{task}"),
                (1200, 500),
            )?;
        }
    }
    Ok(files)
}

/// A figure written through [`figure::write`], object-safe.
trait DynFigure {
    fn write(&self, stem: &Path, size: (u32, u32)) -> Result<(), StudyError>;
}

impl<F: Figure> DynFigure for F {
    fn write(&self, stem: &Path, size: (u32, u32)) -> Result<(), StudyError> {
        figure::write(self, stem, size).map_err(|e| StudyError::Report(e.to_string()))
    }
}

fn colour(i: usize) -> RGBColor {
    COLOURS[i % COLOURS.len()]
}

/// Successes per task (groups) and condition (bars).
struct Bars<'a> {
    r: &'a Report,
}

impl Figure for Bars<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        text: bool,
    ) -> Result<(), String> {
        let r = self.r;
        let k = r.conditions.len().max(1);
        let top = r
            .successes
            .iter()
            .map(|s| s.attempts)
            .max()
            .unwrap_or(1)
            .max(1) as f64;
        let mut b = ChartBuilder::on(root);
        b.margin(20);
        if text {
            b.caption("Successes per task and condition", ("sans-serif", 22))
                .x_label_area_size(40)
                .y_label_area_size(50);
        }
        let mut chart = b
            .build_cartesian_2d(0.0..r.tasks.len() as f64, 0.0..top)
            .map_err(figure::err)?;
        if text {
            let tasks = r.tasks.clone();
            chart
                .configure_mesh()
                .disable_x_mesh()
                .x_labels(r.tasks.len() * 2 + 1)
                .x_label_formatter(&move |x| {
                    let i = x.floor() as usize;
                    if (x - i as f64 - 0.5).abs() < 0.26 {
                        tasks.get(i).cloned().unwrap_or_default()
                    } else {
                        String::new()
                    }
                })
                .y_desc("successful attempts")
                .draw()
                .map_err(figure::err)?;
        }
        let w = 0.8 / k as f64;
        for (ti, task) in r.tasks.iter().enumerate() {
            for (ci, c) in r.conditions.iter().enumerate() {
                let Some(s) = r
                    .successes
                    .iter()
                    .find(|s| &s.task == task && &s.condition == c)
                else {
                    continue;
                };
                let x0 = ti as f64 + 0.1 + ci as f64 * w;
                let bar = chart
                    .draw_series(std::iter::once(Rectangle::new(
                        [(x0, 0.0), (x0 + w * 0.9, s.successes as f64)],
                        colour(ci).filled(),
                    )))
                    .map_err(figure::err)?;
                if ti == 0 {
                    bar.label(c.clone()).legend(move |(x, y)| {
                        Rectangle::new([(x, y - 5), (x + 10, y + 5)], colour(ci).filled())
                    });
                }
            }
        }
        if text {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(figure::err)?;
        }
        Ok(())
    }
}

/// Gaussian kernel density of `v` at `y` with bandwidth `h`.
fn density(v: &[f64], y: f64, h: f64) -> f64 {
    v.iter()
        .map(|x| (-0.5 * ((y - x) / h).powi(2)).exp())
        .sum::<f64>()
        / (v.len() as f64 * h * (2.0 * std::f64::consts::PI).sqrt())
}

/// Silverman's bandwidth, with a floor for samples without spread.
fn bandwidth(v: &[f64], span: f64) -> f64 {
    let m = mean(v);
    let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len().max(2) as f64).sqrt();
    (1.06 * sd * (v.len() as f64).powf(-0.2)).max(span * 0.02)
}

/// Violins of one measure per panel, one per condition; the mean or the median marked.
struct Violins<'a> {
    r: &'a Report,
    panels: Vec<&'a Tested>,
    y: (f64, f64),
    mark_mean: bool,
}

impl Figure for Violins<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        text: bool,
    ) -> Result<(), String> {
        let areas = root.split_evenly((1, self.panels.len().max(1)));
        let k = self.r.conditions.len();
        let (lo, hi) = self.y;
        for (area, m) in areas.iter().zip(&self.panels) {
            let mut b = ChartBuilder::on(area);
            b.margin(12);
            if text {
                let title = if m.kind == "completion" {
                    m.task.clone()
                } else {
                    m.measure.clone()
                };
                b.caption(title, ("sans-serif", 18))
                    .x_label_area_size(30)
                    .y_label_area_size(40);
            }
            let mut chart = b
                .build_cartesian_2d(-0.5..k as f64 - 0.5, lo..hi)
                .map_err(figure::err)?;
            if text {
                let names = self.r.conditions.clone();
                chart
                    .configure_mesh()
                    .disable_x_mesh()
                    .x_labels(k)
                    .x_label_formatter(&move |x| {
                        let i = x.round();
                        if (x - i).abs() < 0.01 && i >= 0.0 {
                            names.get(i as usize).cloned().unwrap_or_default()
                        } else {
                            String::new()
                        }
                    })
                    .draw()
                    .map_err(figure::err)?;
            }
            for (ci, v) in m.values.iter().enumerate() {
                if v.is_empty() {
                    continue;
                }
                let h = bandwidth(v, hi - lo);
                let steps = 80;
                let ys: Vec<f64> = (0..=steps)
                    .map(|i| lo + (hi - lo) * i as f64 / steps as f64)
                    .collect();
                let d: Vec<f64> = ys.iter().map(|y| density(v, *y, h)).collect();
                let top = d.iter().copied().fold(0.0, f64::max).max(f64::MIN_POSITIVE);
                let x = ci as f64;
                let mut outline: Vec<(f64, f64)> = ys
                    .iter()
                    .zip(&d)
                    .map(|(y, d)| (x + 0.4 * d / top, *y))
                    .collect();
                outline.extend(
                    ys.iter()
                        .zip(&d)
                        .rev()
                        .map(|(y, d)| (x - 0.4 * d / top, *y)),
                );
                chart
                    .draw_series(std::iter::once(Polygon::new(
                        outline,
                        colour(ci).mix(0.5).filled(),
                    )))
                    .map_err(figure::err)?;
                chart
                    .draw_series(v.iter().map(|y| Circle::new((x, *y), 2, BLACK.filled())))
                    .map_err(figure::err)?;
                let c = if self.mark_mean { mean(v) } else { median(v) };
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        vec![(x - 0.3, c), (x + 0.3, c)],
                        BLACK.stroke_width(3),
                    )))
                    .map_err(figure::err)?;
            }
        }
        Ok(())
    }
}

/// Likert medians per item (spokes) and condition (polygons); a star where a condition
/// differs from the reference (Dunn, Holm).
struct Radar<'a> {
    r: &'a Report,
    items: Vec<&'a Tested>,
}

impl Figure for Radar<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        text: bool,
    ) -> Result<(), String> {
        let (w, h) = root.dim_in_pixel();
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        let radius = w.min(h) as f64 * 0.32;
        let n = self.items.len().max(1);
        let top = self
            .items
            .iter()
            .flat_map(|m| m.values.iter().flatten())
            .copied()
            .fold(5.0, f64::max)
            .max(5.0);
        let scale = if top > 5.0 { 7.0 } else { 5.0 };
        let at = |i: usize, v: f64| {
            let a = -std::f64::consts::FRAC_PI_2 + 2.0 * std::f64::consts::PI * i as f64 / n as f64;
            let r = radius * ((v - 1.0) / (scale - 1.0)).clamp(0.0, 1.0);
            ((cx + r * a.cos()) as i32, (cy + r * a.sin()) as i32)
        };
        for ring in 1..=scale as usize {
            let pts: Vec<(i32, i32)> = (0..=n).map(|i| at(i % n, ring as f64)).collect();
            root.draw(&PathElement::new(pts, RGBColor(200, 200, 200)))
                .map_err(figure::err)?;
        }
        for i in 0..n {
            root.draw(&PathElement::new(
                vec![at(i, 1.0), at(i, scale)],
                RGBColor(160, 160, 160),
            ))
            .map_err(figure::err)?;
            if text {
                let (x, y) = at(i, scale + 0.6);
                // "Control: I felt in control" -> "Control"; else the first words.
                let item = &self.items[i].measure;
                let label: String = match item.split_once(':') {
                    Some((head, _)) => head.to_owned(),
                    None => item.chars().take(28).collect(),
                };
                root.draw(&Text::new(label, (x - 60, y), ("sans-serif", 14)))
                    .map_err(figure::err)?;
            }
        }
        for ci in 0..self.r.conditions.len() {
            let pts: Vec<(i32, i32)> = (0..=n)
                .map(|i| at(i % n, median(&self.items[i % n].values[ci])))
                .collect();
            root.draw(&PathElement::new(pts, colour(ci).stroke_width(3)))
                .map_err(figure::err)?;
            for (i, m) in self.items.iter().enumerate() {
                if m.differ_from(self.r.reference).contains(&ci) {
                    let (x, y) = at(i, median(&m.values[ci]));
                    if text {
                        root.draw(&Text::new(
                            "*",
                            (x + 4, y - 18),
                            ("sans-serif", 28).into_font().color(&colour(ci)),
                        ))
                        .map_err(figure::err)?;
                    } else {
                        root.draw(&Circle::new((x, y), 7, colour(ci).filled()))
                            .map_err(figure::err)?;
                    }
                }
            }
            if text {
                root.draw(&Text::new(
                    self.r.conditions[ci].clone(),
                    (20, 20 + 22 * ci as i32),
                    ("sans-serif", 18).into_font().color(&colour(ci)),
                ))
                .map_err(figure::err)?;
            }
        }
        Ok(())
    }
}
