//! Draws a robot profile's collision model over its kinematic skeleton at two poses, from the
//! side (x-z) and from above (x-y): the Gen3 lite's into `docs/collision-model.png`, the
//! Gen3's into `docs/collision-model-gen3.png`.
//!
//! Regenerate: `cargo run -p kinematics --example draw_collision` (the Gen3 lite) and
//! `cargo run -p kinematics --example draw_collision -- --robot gen3`; another output path
//! may follow as the last argument.
//!
//! Each capsule is drawn as its exact outline in the view (a capsule seen along an axis is
//! the 2-D capsule of the projected segment, same radius), tinted by link, margin included;
//! the black line joins the joint origins from the base to the flange, the fingers' joints and
//! the TCP (dots). The closest pair of the pose is joined by a red line between its closest
//! points; the grey line is the table (z = 0).
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

use kinematics::collision::{Clearance, CollisionModel, Scene};
use kinematics::{RobotProfile, gen3, gen3_lite};
use nalgebra::{Point3, Vector2};
use plotters::coord::Shift;
use plotters::prelude::*;

const SIZE: (u32, u32) = (1400, 1300);
const FONT: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";

/// Colours by link index: the known links' (the Gen3 lite's, then the Gen3's own), and for a
/// new arm's links the palette again.
const COLOURS: [RGBColor; 16] = [
    RGBColor(110, 110, 110), // base
    RGBColor(31, 119, 180),  // shoulder
    RGBColor(44, 160, 44),   // arm
    RGBColor(255, 127, 14),  // forearm
    RGBColor(148, 103, 189), // lower wrist
    RGBColor(23, 190, 207),  // upper wrist
    RGBColor(140, 86, 75),   // gripper base
    RGBColor(214, 39, 40),   // right finger prox
    RGBColor(227, 119, 194), // right finger dist
    RGBColor(188, 189, 34),  // left finger prox
    RGBColor(127, 127, 127), // left finger dist
    RGBColor(44, 160, 44),   // half arm 1
    RGBColor(255, 127, 14),  // half arm 2
    RGBColor(148, 103, 189), // spherical wrist 1
    RGBColor(23, 190, 207),  // spherical wrist 2
    RGBColor(188, 189, 34),  // bracelet
];

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// The outline of a 2-D capsule: the projected segment `a-b` swept by a disc of radius `r`.
fn outline(a: Vector2<f64>, b: Vector2<f64>, r: f64) -> Vec<(f64, f64)> {
    let d = b - a;
    let u = if d.norm() > 1e-9 {
        d / d.norm()
    } else {
        Vector2::new(1.0, 0.0)
    };
    let v = Vector2::new(-u.y, u.x);
    let mut pts = Vec::with_capacity(66);
    // Half a turn about each end, from `from` through the outward direction `out` (given per
    // end: a segment seen end-on projects both ends onto one point).
    for (centre, from, out) in [(b, -v, u), (a, v, -u)] {
        for k in 0..=32 {
            let t = std::f64::consts::PI * f64::from(k) / 32.0;
            let p = centre + (from * t.cos() + out * t.sin()) * r;
            pts.push((p.x, p.y));
        }
    }
    pts
}

struct Pose {
    name: &'static str,
    q: Vec<f64>,
}

/// The joint origins along the arm chain, base to TCP.
fn skeleton(robot: &RobotProfile, q: &[f64]) -> Vec<Point3<f64>> {
    let arm = robot.arm();
    let n = arm.n_joints();
    arm.link_names()
        .map(|l| {
            let t = arm.link_pose(&q[..n], arm.link_id(l).unwrap()).unwrap();
            Point3::from(t.translation.vector)
        })
        .collect()
}

#[allow(clippy::too_many_arguments)]
fn view(
    area: &Area<'_>,
    caption: &str,
    (i, j): (usize, usize),
    (xr, yr): (std::ops::Range<f64>, std::ops::Range<f64>),
    out: &Clearance,
    model: &CollisionModel,
    skel: &[Point3<f64>],
    table: bool,
) {
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 17))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(xr.clone(), yr)
        .unwrap();
    let names = ["x (m)", "y (m)", "z (m)"];
    chart
        .configure_mesh()
        .light_line_style(RGBColor(235, 235, 235))
        .x_desc(names[i])
        .y_desc(names[j])
        .label_style(("sans-serif", 14))
        .draw()
        .unwrap();
    if table {
        chart
            .draw_series(LineSeries::new(
                [(xr.start, 0.0), (xr.end, 0.0)],
                RGBColor(120, 120, 120).stroke_width(3),
            ))
            .unwrap();
    }
    let p2 = |p: &Point3<f64>| Vector2::new(p[i], p[j]);
    for (c, r) in out.capsules().iter().zip(model.capsule_refs()) {
        let colour = COLOURS[r.link.index() % COLOURS.len()];
        let pts = outline(p2(&c.a), p2(&c.b), c.radius_m);
        chart
            .draw_series(std::iter::once(Polygon::new(
                pts.clone(),
                colour.mix(0.25).filled(),
            )))
            .unwrap();
        let mut closed = pts;
        closed.push(closed[0]);
        chart
            .draw_series(std::iter::once(PathElement::new(
                closed,
                colour.stroke_width(2),
            )))
            .unwrap();
    }
    let line: Vec<(f64, f64)> = skel.iter().map(|p| (p[i], p[j])).collect();
    chart
        .draw_series(LineSeries::new(line.clone(), BLACK.stroke_width(2)))
        .unwrap();
    chart
        .draw_series(line.iter().map(|p| Circle::new(*p, 3, BLACK.filled())))
        .unwrap();
    if let Some(c) = out.closest() {
        chart
            .draw_series(LineSeries::new(
                [(c.point_a[i], c.point_a[j]), (c.point_b[i], c.point_b[j])],
                RED.stroke_width(3),
            ))
            .unwrap();
        chart
            .draw_series(
                [c.point_a, c.point_b]
                    .iter()
                    .map(|p| Circle::new((p[i], p[j]), 4, RED.filled())),
            )
            .unwrap();
    }
}

/// Equal-aspect ranges of the axes `i`, `j` covering every capsule of every pose.
fn ranges(
    outs: &[Clearance],
    (i, j): (usize, usize),
    (w, h): (f64, f64),
) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for out in outs {
        for c in out.capsules() {
            for p in [c.a, c.b] {
                x0 = x0.min(p[i] - c.radius_m);
                x1 = x1.max(p[i] + c.radius_m);
                y0 = y0.min(p[j] - c.radius_m);
                y1 = y1.max(p[j] + c.radius_m);
            }
        }
    }
    let pad = 0.04;
    let (x0, x1, y0, y1) = (x0 - pad, x1 + pad, y0 - pad, y1 + pad);
    let scale = ((x1 - x0) / w).max((y1 - y0) / h);
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    (
        cx - scale * w / 2.0..cx + scale * w / 2.0,
        cy - scale * h / 2.0..cy + scale * h / 2.0,
    )
}

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let robot_name = match args.iter().position(|a| a == "--robot") {
        Some(k) if k + 1 < args.len() => {
            let name = args.remove(k + 1);
            args.remove(k);
            name
        }
        _ => "gen3_lite".to_owned(),
    };
    let robot = RobotProfile::by_name(&robot_name).unwrap();
    let default_png = if robot_name == "gen3_lite" {
        "collision-model.png".to_owned()
    } else {
        format!("collision-model-{robot_name}.png")
    };
    let path = args.first().map_or_else(
        || PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/")).join(&default_png),
        PathBuf::from,
    );
    let font: &'static [u8] = Box::leak(std::fs::read(FONT).unwrap().into_boxed_slice());
    plotters::style::register_font("sans-serif", FontStyle::Normal, font)
        .map_err(|_| "not a font")
        .unwrap();
    let model: &CollisionModel = robot.collision_model().unwrap();
    let scene = Scene::default();
    let poses = if robot_name == "gen3" {
        // Kinova's two poses; retract folds the gripper down beside the shoulder.
        [
            Pose {
                name: "home",
                q: gen3::HOME.to_vec(),
            },
            Pose {
                name: "retract",
                q: gen3::RETRACT.to_vec(),
            },
        ]
    } else {
        let mut near = vec![0.0, 2.2, 0.5, 0.0, 0.0, 0.0];
        near.push(0.4);
        [
            Pose {
                name: "home, gripper open",
                q: gen3_lite::HOME.to_vec(),
            },
            Pose {
                name: "q = (0, 2.2, 0.5, 0, 0, 0), gripper 0.4",
                q: near,
            },
        ]
    };
    let outs: Vec<Clearance> = poses
        .iter()
        .map(|p| {
            let mut out = Clearance::default();
            model.clearance(&p.q, &scene, &mut out).unwrap();
            out
        })
        .collect();
    let (w, h) = SIZE;
    let mut buf = vec![0u8; (w as usize) * (h as usize) * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).unwrap();
        let body = root
            .titled(
                &format!(
                    "{} collision model: {} capsules (margin {} mm included), {} self pairs, table at z = 0; red: the closest pair",
                    robot.description(),
                    model.capsule_refs().len(),
                    model.margin_m() * 1e3,
                    model.self_pairs().len()
                ),
                ("sans-serif", 24),
            )
            .unwrap();
        let rows = body.split_evenly((2, 2));
        let panel = (f64::from(w / 2 - 80), f64::from(h / 2 - 110));
        let side = ranges(&outs, (0, 2), panel);
        let top = ranges(&outs, (0, 1), panel);
        for (k, (pose, out)) in poses.iter().zip(&outs).enumerate() {
            let c = out.closest().unwrap();
            let skel = skeleton(robot, &pose.q);
            let caption = format!(
                "{} (side): closest {}, {:.0} mm",
                pose.name,
                c.pair,
                c.distance_m * 1e3
            );
            view(
                &rows[2 * k],
                &caption,
                (0, 2),
                side.clone(),
                out,
                model,
                &skel,
                true,
            );
            view(
                &rows[2 * k + 1],
                &format!("{} (from above)", pose.name),
                (0, 1),
                top.clone(),
                out,
                model,
                &skel,
                false,
            );
        }
        root.present().unwrap();
    }
    let file = std::fs::File::create(&path).unwrap();
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().unwrap();
    writer.write_image_data(&buf).unwrap();
    writer.finish().unwrap();
    println!("wrote {}", path.display());
}
