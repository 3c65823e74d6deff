//! `scl plot`: the tool-centre-point paths of a data set's demonstrations, drawn to a PNG.
//!
//! Joint-space trajectories go through the robot's forward kinematics (the Gen3 lite for 6
//! joints, the planar arm for 5) and are drawn from above (x-y) and from the side (x-z, the
//! table at z = 0); the planar arm gets the top view only, with the line its targets lie on.
//! Training trajectories are solid, validation ones dashed; a path is drawn thicker where the
//! gripper is closed (c >= 0.5); a dot marks each start, a square the robot's base.
//!
//! Drawing uses `plotters` into an RGB buffer and the `png` crate to encode it. Text needs a
//! TrueType font read at run time (`--font`, else a few common system paths); without one the
//! figure is drawn without any text.

use std::path::{Path, PathBuf};

use crate::dataset::Dataset;
use crate::tasks::{PLANAR_LINE_FROM, PLANAR_LINE_TO};
use kinematics::{Chain, KinError, planar5};
use plotters::coord::Shift;
use plotters::prelude::*;

/// Where `scl plot` looks for a font when `--font` is not given.
pub const FONT_CANDIDATES: [&str; 5] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/liberation-sans/LiberationSans-Regular.ttf",
];

/// Image size (pixels).
pub const SIZE: (u32, u32) = (1400, 720);

/// Why a plot could not be made.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// No robot model has this many joints.
    #[error(
        "the data has {0} joints; plots know the robot profiles' arms (the Gen3 lite 6, the \
         Gen3 7) and the planar arm (5 joints)"
    )]
    NoRobot(usize),
    /// Forward kinematics refused a row.
    #[error("trajectory {trajectory}: {source}")]
    Kinematics {
        /// The trajectory.
        trajectory: String,
        /// The kinematics error.
        source: KinError,
    },
    /// The font file is unusable.
    #[error("{path}: {reason}")]
    Font {
        /// The font file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Drawing failed.
    #[error("drawing the plot failed: {0}")]
    Draw(String),
    /// The output exists and `--force` was not given.
    #[error("{0} already exists; pass --force to replace it")]
    Exists(PathBuf),
    /// Writing the PNG failed.
    #[error("{path}: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
}

fn draw_err<E: std::error::Error + Send + Sync>(e: DrawingAreaErrorKind<E>) -> PlotError {
    PlotError::Draw(e.to_string())
}

/// One point of a TCP path: position (m) and whether the gripper is closed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathPoint {
    /// Position in the base frame (m).
    pub p: [f64; 3],
    /// Gripper closed (c >= 0.5).
    pub closed: bool,
}

/// A TCP path: one point per tuple.
pub type TcpPath = Vec<PathPoint>;

/// The TCP paths of every trajectory: (training, validation), through the forward kinematics
/// of the robot with the data's joint count (a built-in profile's, or the planar arm's).
pub fn tcp_paths(ds: &Dataset) -> Result<(Vec<TcpPath>, Vec<TcpPath>), PlotError> {
    let m = ds
        .train
        .iter()
        .chain(&ds.val)
        .map(|t| t.n_joints())
        .find(|m| *m > 0)
        .unwrap_or(0);
    // The planar arm's five joints, else the first built-in profile with the data's joints
    // (six: the Gen3 lite; seven: the Gen3).
    let profile = kinematics::RobotProfile::names()
        .filter_map(|name| kinematics::RobotProfile::by_name(name).ok())
        .find(|p| p.n_joints() == m);
    let chain: &Chain = match (m, profile) {
        (5, _) => planar5::get(),
        (_, Some(p)) => p.arm(),
        (other, None) => return Err(PlotError::NoRobot(other)),
    };
    let paths = |trajs: &[crate::dataset::Trajectory]| -> Result<Vec<TcpPath>, PlotError> {
        trajs
            .iter()
            .map(|t| {
                t.q.iter()
                    .zip(&t.c)
                    .map(|(q, c)| {
                        let x = chain.fk(q).map_err(|source| PlotError::Kinematics {
                            trajectory: t.name.clone(),
                            source,
                        })?;
                        let v = x.translation.vector;
                        Ok(PathPoint {
                            p: [v.x, v.y, v.z],
                            closed: *c >= 0.5,
                        })
                    })
                    .collect()
            })
            .collect()
    };
    Ok((paths(&ds.train)?, paths(&ds.val)?))
}

/// Reads a font for the figure's text: `explicit` if given (an error if unusable), else the
/// first of [`FONT_CANDIDATES`] that exists; `None` when there is none (then the figure has
/// no text). The bytes live for the rest of the process, as the drawing library requires.
pub fn load_font(explicit: Option<&Path>) -> Result<Option<&'static [u8]>, PlotError> {
    let path = match explicit {
        Some(p) => p.to_owned(),
        None => match FONT_CANDIDATES.iter().map(Path::new).find(|p| p.is_file()) {
            Some(p) => p.to_owned(),
            None => return Ok(None),
        },
    };
    let bytes = std::fs::read(&path).map_err(|e| PlotError::Font {
        path: path.clone(),
        reason: e.to_string(),
    })?;
    let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
    plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).map_err(|_| {
        PlotError::Font {
            path: path.clone(),
            reason: "not a TrueType / OpenType font".into(),
        }
    })?;
    tracing::debug!(font = %path.display(), "plot font");
    Ok(Some(bytes))
}

const TRAIN_COLOURS: [RGBColor; 4] = [
    RGBColor(31, 119, 180),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(23, 190, 207),
];
const VAL_COLOURS: [RGBColor; 3] = [
    RGBColor(214, 39, 40),
    RGBColor(255, 127, 14),
    RGBColor(140, 86, 75),
];

/// Axis ranges covering `points` (and `y = 0` if `with_y_zero`), padded, and widened so
/// that a metre is as long on both axes of a `w` x `h` pixel area.
fn equal_ranges(
    points: impl Iterator<Item = (f64, f64)>,
    with_y_zero: bool,
    w: f64,
    h: f64,
) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    if with_y_zero {
        (y0, y1) = (0.0, 0.0);
    }
    for (x, y) in points {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 > x1 || y0 > y1 {
        (x0, x1, y0, y1) = (0.0, 0.0, 0.0, 0.0);
    }
    let pad = 0.05 * (x1 - x0).max(y1 - y0).max(0.1);
    let (mut x0, mut x1, mut y0, mut y1) = (x0 - pad, x1 + pad, y0 - pad, y1 + pad);
    let scale = ((x1 - x0) / w).max((y1 - y0) / h);
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    x0 = cx - scale * w / 2.0;
    x1 = cx + scale * w / 2.0;
    y0 = cy - scale * h / 2.0;
    y1 = cy + scale * h / 2.0;
    (x0..x1, y0..y1)
}

type Paths = [TcpPath];
type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// What a view draws besides the paths.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Backdrop {
    /// The planar arm's target line (top view).
    TargetLine,
    /// The table plane z = 0 (side view).
    Table,
    /// Nothing.
    Nothing,
}

/// Draws one view of the paths: axes `a` and `b` of each point (0 = x, 1 = y, 2 = z).
fn draw_view(
    area: &Area<'_>,
    caption: &str,
    (a, b): (usize, usize),
    (a_name, b_name): (&str, &str),
    (train, val): (&Paths, &Paths),
    text: bool,
    backdrop: Backdrop,
) -> Result<(), PlotError> {
    let (w, h) = area.dim_in_pixel();
    let (label, caption_h) = if text { (45u32, 30u32) } else { (10, 0) };
    let all = train.iter().chain(val).flatten().map(|p| (p.p[a], p.p[b]));
    let (xr, yr) = equal_ranges(
        all,
        backdrop == Backdrop::Table,
        f64::from(w.saturating_sub(label + 30)),
        f64::from(h.saturating_sub(label + caption_h + 20)),
    );
    let (x_start, x_end) = (xr.start, xr.end);
    let base_visible = xr.contains(&0.0) && yr.contains(&0.0);
    let mut builder = ChartBuilder::on(area);
    builder
        .margin(10)
        .x_label_area_size(label)
        .y_label_area_size(label);
    if text {
        builder.caption(caption, ("sans-serif", 22));
    }
    let mut chart = builder.build_cartesian_2d(xr, yr).map_err(draw_err)?;
    let mut mesh = chart.configure_mesh();
    mesh.light_line_style(RGBColor(235, 235, 235));
    if text {
        mesh.x_desc(format!("{a_name} (m)"))
            .y_desc(format!("{b_name} (m)"))
            .label_style(("sans-serif", 15));
    } else {
        mesh.x_labels(0).y_labels(0);
    }
    mesh.draw().map_err(draw_err)?;
    let grey = RGBColor(120, 120, 120).stroke_width(2);
    match backdrop {
        Backdrop::TargetLine => {
            chart
                .draw_series(DashedLineSeries::new(
                    [
                        (PLANAR_LINE_FROM[0], PLANAR_LINE_FROM[1]),
                        (PLANAR_LINE_TO[0], PLANAR_LINE_TO[1]),
                    ],
                    6,
                    4,
                    grey,
                ))
                .map_err(draw_err)?;
        }
        Backdrop::Table => {
            chart
                .draw_series(LineSeries::new([(x_start, 0.0), (x_end, 0.0)], grey))
                .map_err(draw_err)?;
        }
        Backdrop::Nothing => {}
    }
    if base_visible {
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(-0.015, -0.015), (0.015, 0.015)],
                BLACK.filled(),
            )))
            .map_err(draw_err)?;
    }
    for (split, (paths, colours)) in [(train, &TRAIN_COLOURS[..]), (val, &VAL_COLOURS[..])]
        .into_iter()
        .enumerate()
    {
        for (i, path) in paths.iter().enumerate() {
            let colour = colours[i % colours.len()];
            // Runs of equal gripper state, each drawn as one series (thicker when closed);
            // consecutive runs share their boundary point.
            let mut start = 0;
            while start + 1 < path.len() {
                let closed = path[start].closed;
                let mut end = start + 1;
                while end + 1 < path.len() && path[end].closed == closed {
                    end += 1;
                }
                let pts: Vec<(f64, f64)> =
                    path[start..=end].iter().map(|p| (p.p[a], p.p[b])).collect();
                let style = colour.stroke_width(if closed { 5 } else { 2 });
                if split == 0 {
                    chart
                        .draw_series(LineSeries::new(pts, style))
                        .map_err(draw_err)?;
                } else {
                    chart
                        .draw_series(DashedLineSeries::new(pts, 9, 6, style))
                        .map_err(draw_err)?;
                }
                start = end;
            }
            if let Some(first) = path.first() {
                chart
                    .draw_series(std::iter::once(Circle::new(
                        (first.p[a], first.p[b]),
                        5,
                        colour.filled(),
                    )))
                    .map_err(draw_err)?;
            }
        }
    }
    Ok(())
}

/// Renders the figure into an RGB buffer of [`SIZE`].
pub fn render(ds: &Dataset, title: &str, text: bool) -> Result<Vec<u8>, PlotError> {
    let (train, val) = tcp_paths(ds)?;
    let planar = ds.train.iter().chain(&ds.val).any(|t| t.n_joints() == 5);
    let (w, h) = SIZE;
    let mut buf = vec![0u8; (w as usize) * (h as usize) * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let body = if text {
            root.titled(title, ("sans-serif", 26)).map_err(draw_err)?
        } else {
            root.clone()
        };
        let paths = (&train[..], &val[..]);
        if planar {
            draw_view(
                &body,
                "TCP from above (x-y); dashed grey: the target line",
                (0, 1),
                ("x", "y"),
                paths,
                text,
                Backdrop::TargetLine,
            )?;
        } else {
            let (left, right) = body.split_horizontally(body.dim_in_pixel().0 / 2);
            draw_view(
                &left,
                "TCP from above (x-y); dots: starts",
                (0, 1),
                ("x", "y"),
                paths,
                text,
                Backdrop::Nothing,
            )?;
            draw_view(
                &right,
                "TCP from the side (x-z); grey: the table",
                (0, 2),
                ("x", "z"),
                paths,
                text,
                Backdrop::Table,
            )?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(buf)
}

/// Encodes an RGB buffer of [`SIZE`] as a PNG file; refuses to replace a file unless `force`.
pub fn write_png(path: &Path, rgb: &[u8], force: bool) -> Result<(), PlotError> {
    if path.exists() && !force {
        return Err(PlotError::Exists(path.to_owned()));
    }
    let write_err = |reason: String| PlotError::Write {
        path: path.to_owned(),
        reason,
    };
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| write_err(e.to_string()))?;
    }
    let file = std::fs::File::create(path).map_err(|e| write_err(e.to_string()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), SIZE.0, SIZE.1);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().map_err(|e| write_err(e.to_string()))?;
    writer
        .write_image_data(rgb)
        .map_err(|e| write_err(e.to_string()))?;
    writer.finish().map_err(|e| write_err(e.to_string()))?;
    Ok(())
}

/// A default title: the data's name and its counts.
pub fn title_for(name: &str, ds: &Dataset) -> String {
    format!(
        "{name}: {} training ({} tuples, solid), {} validation ({} tuples, dashed); thick: gripper closed",
        ds.train.len(),
        ds.n_train(),
        ds.val.len(),
        ds.n_val()
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tasks::{Task, generate};

    #[test]
    fn ranges_are_equal_aspect_and_cover_the_points() {
        let pts = [(0.2, 0.1), (0.5, 0.3)];
        let (x, y) = equal_ranges(pts.into_iter(), false, 600.0, 300.0);
        let (mx, my) = ((x.end - x.start) / 600.0, (y.end - y.start) / 300.0);
        assert!((mx - my).abs() < 1e-12);
        assert!(x.start < 0.2 && x.end > 0.5 && y.start < 0.1 && y.end > 0.3);
        assert!(x.start > 0.0 && y.start > 0.0);
        let (_, y) = equal_ranges(pts.into_iter(), true, 600.0, 300.0);
        assert!(y.start < 0.0);
    }

    #[test]
    fn paths_follow_the_kinematics() {
        let ds = generate(Task::PickAndPlace, 1, 1, 3).unwrap();
        let (train, val) = tcp_paths(&ds).unwrap();
        assert_eq!(train.len(), 1);
        assert_eq!(val.len(), 1);
        assert_eq!(train[0].len(), ds.train[0].len());
        // Home TCP first; the gripper closes somewhere along the way.
        assert!((train[0][0].p[0] - 0.43882).abs() < 1e-4);
        assert!(train[0].iter().any(|p| p.closed));
        let mut bad = ds.clone();
        for t in &mut bad.train {
            for q in &mut t.q {
                q.push(0.0);
                q.push(0.0);
            }
        }
        assert!(matches!(tcp_paths(&bad), Err(PlotError::NoRobot(8))));
        // Seven joints: the Gen3's, from its home.
        let gen3 = kinematics::RobotProfile::by_name("gen3").unwrap();
        let ds = crate::tasks::generate_for(Task::PickAndPlace, gen3, 1, 0, 3).unwrap();
        let (train, _) = tcp_paths(&ds).unwrap();
        let home = gen3.arm().fk(gen3.named_pose("home").unwrap()).unwrap();
        assert!((train[0][0].p[0] - home.translation.x).abs() < 1e-9);
    }

    #[test]
    fn renders_without_a_font_and_refuses_to_overwrite() {
        let ds = generate(Task::PlanarReach, 2, 1, 1).unwrap();
        let rgb = render(&ds, "t", false).unwrap();
        assert_eq!(rgb.len(), (SIZE.0 * SIZE.1 * 3) as usize);
        // Something other than the white background was drawn.
        assert!(rgb.chunks(3).filter(|p| p != &[255, 255, 255]).count() > 1000);
        let dir = std::env::temp_dir().join(format!("scl-plot-{}", std::process::id()));
        let file = dir.join("p.png");
        let _ = std::fs::remove_dir_all(&dir);
        write_png(&file, &rgb, false).unwrap();
        let bytes = std::fs::read(&file).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        assert!(matches!(
            write_png(&file, &rgb, false),
            Err(PlotError::Exists(_))
        ));
        write_png(&file, &rgb, true).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_bad_font_file_is_named() {
        let dir = std::env::temp_dir().join(format!("scl-font-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("not-a-font.ttf");
        std::fs::write(&f, b"hello").unwrap();
        let e = load_font(Some(&f)).unwrap_err().to_string();
        assert!(
            e.ends_with("not-a-font.ttf: not a TrueType / OpenType font"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
