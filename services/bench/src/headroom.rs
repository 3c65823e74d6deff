//! `scl bench headroom`: the same graph at rising rates (40, 100, 250, 500 and 1000 Hz by
//! default), each run like `scl bench latency`, reduced to what says how much room the machine
//! leaves: missed ticks (and how many of them the machine took), end to end p50 / p99 / max,
//! the tick lateness, and each process's CPU time per tick; as a table, JSON and a plot.

use std::path::PathBuf;
use std::time::Duration;

use ipc_types::Transport;
use serde::Serialize;
use transport::signals;

use crate::{BenchError, Dist, LatencyOptions, Machine, RtSettings, run_one};

/// The rates `scl bench headroom` runs by default (Hz).
pub const DEFAULT_RATES: [f64; 5] = [40.0, 100.0, 250.0, 500.0, 1000.0];

/// What `scl bench headroom` was asked to do.
#[derive(Debug, Clone)]
pub struct HeadroomOptions {
    /// The rates, in the order they run (Hz).
    pub rates: Vec<f64>,
    /// How long each rate runs on each transport.
    pub duration: Duration,
    /// The real-time settings asked for.
    pub rt: RtSettings,
    /// Busy processes beside the graph.
    pub load: usize,
    /// The transports, each at every rate.
    pub transports: Vec<Transport>,
    /// The base configuration (rate, transport and real-time settings are overridden).
    pub config: scl_config::GraphConfig,
    /// Where to keep the report, the plot, and every run's config and log.
    pub out: Option<PathBuf>,
}

/// One rate on one transport.
#[derive(Debug, Clone, Serialize)]
pub struct HeadroomRow {
    /// The rate (Hz).
    pub rate_hz: f64,
    /// The transport.
    pub transport: Transport,
    /// Ticks observed.
    pub ticks: u64,
    /// Ticks missed (the bridge's count).
    pub missed: u64,
    /// Of those, the machine's (`held_up`): periods the bridge was not run through and late
    /// commands whose work fitted the deadline.
    pub held_up: u64,
    /// RobotState(k) published -> SafeCommand(k) received (µs).
    pub e2e_us: Dist,
    /// The bridge's wake-up lateness against the ideal grid (µs).
    pub tick_lateness_us: Dist,
    /// Each process's CPU time per tick (µs).
    pub cpu_per_tick_us: Vec<(String, f64)>,
    /// All processes' CPU time per tick (µs).
    pub cpu_total_per_tick_us: f64,
    /// The graph's share of one CPU at this rate (total per tick × rate).
    pub cpu_share: f64,
    /// Each process's share of one CPU.
    pub process_cpu_share: Vec<(String, f64)>,
    /// Each polling process's polling time per tick (µs; `[graph] wait`).
    pub spin_us_per_tick: Vec<(String, f64)>,
}

/// The whole result (`--json`, `report.json`).
#[derive(Debug, Clone, Serialize)]
pub struct HeadroomReport {
    /// The machine.
    pub machine: Machine,
    /// Seconds per rate and transport.
    pub duration_s: f64,
    /// The real-time settings asked for.
    pub rt_settings: RtSettings,
    /// `--load` busy processes.
    pub load: usize,
    /// The mapper's model.
    pub model: String,
    /// How the control path waited (`[graph] wait`).
    pub wait: scl_config::WaitStrategy,
    /// One row per rate and transport, rates in order.
    pub rows: Vec<HeadroomRow>,
    /// With both transports: per rate, iceoryx2 / uds of end to end p50, p99, max and of the
    /// total CPU per tick.
    pub ratios: Vec<HeadroomRatio>,
}

/// iceoryx2 / uds at one rate (below 1: iceoryx2 ahead).
#[derive(Debug, Clone, Serialize)]
pub struct HeadroomRatio {
    /// The rate (Hz).
    pub rate_hz: f64,
    /// End to end p50.
    pub e2e_p50: f64,
    /// End to end p99.
    pub e2e_p99: f64,
    /// End to end max.
    pub e2e_max: f64,
    /// Tick lateness p99.
    pub lateness_p99: f64,
    /// CPU per tick, all processes.
    pub cpu_per_tick: f64,
}

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 { a / b } else { f64::NAN }
}

/// Runs the graph at every rate on every transport.
pub fn headroom(opts: &HeadroomOptions) -> Result<HeadroomReport, BenchError> {
    let dir = match &opts.out {
        Some(d) => d.clone(),
        None => std::env::temp_dir().join(format!("scl-headroom-{}", std::process::id())),
    };
    std::fs::create_dir_all(&dir)
        .map_err(|e| BenchError::Graph(format!("{}: {e}", dir.display())))?;
    let mut rows = Vec::new();
    'rates: for &rate in &opts.rates {
        let mut config = opts.config.clone();
        config.set_rate_hz(rate);
        config.validate()?;
        let lat = LatencyOptions {
            duration: opts.duration,
            rt: opts.rt,
            load: opts.load,
            transports: opts.transports.clone(),
            waits: vec![config.graph.wait],
            config,
            out: None,
            live: false,
        };
        for t in &opts.transports {
            if signals::stop_requested() {
                break 'rates;
            }
            let (run, _) = run_one(&lat, *t, lat.config.graph.wait, &dir, &format!("-{rate}hz"))?;
            let total: f64 = run.cpu_per_tick_us.iter().map(|(_, us)| us).sum();
            rows.push(HeadroomRow {
                rate_hz: rate,
                transport: *t,
                ticks: run.ticks,
                missed: run.missed,
                held_up: run.held_up,
                e2e_us: run.e2e_us,
                tick_lateness_us: run.tick_lateness_us,
                cpu_per_tick_us: run.cpu_per_tick_us,
                cpu_total_per_tick_us: total,
                cpu_share: total * rate * 1e-6,
                process_cpu_share: run.cpu_share,
                spin_us_per_tick: run.spin_us_per_tick,
            });
        }
    }
    let mut ratios = Vec::new();
    for &rate in &opts.rates {
        let find = |t| rows.iter().find(|r| r.rate_hz == rate && r.transport == t);
        if let (Some(i), Some(u)) = (find(Transport::Iceoryx2), find(Transport::Uds)) {
            ratios.push(HeadroomRatio {
                rate_hz: rate,
                e2e_p50: ratio(i.e2e_us.p50, u.e2e_us.p50),
                e2e_p99: ratio(i.e2e_us.p99, u.e2e_us.p99),
                e2e_max: ratio(i.e2e_us.max, u.e2e_us.max),
                lateness_p99: ratio(i.tick_lateness_us.p99, u.tick_lateness_us.p99),
                cpu_per_tick: ratio(i.cpu_total_per_tick_us, u.cpu_total_per_tick_us),
            });
        }
    }
    let report = HeadroomReport {
        machine: Machine::detect(),
        duration_s: opts.duration.as_secs_f64(),
        rt_settings: opts.rt,
        load: opts.load,
        model: opts.config.mapper.model.clone(),
        wait: opts.config.graph.wait,
        rows,
        ratios,
    };
    if opts.out.is_some() {
        let font = learning::plot::load_font(None).map_err(|e| BenchError::Graph(e.to_string()))?;
        let rgb =
            render_plot(&report, font.is_some()).map_err(|e| BenchError::Graph(e.to_string()))?;
        let png = dir.join("headroom.png");
        learning::plot::write_png(&png, &rgb, true)
            .map_err(|e| BenchError::Graph(e.to_string()))?;
        eprintln!("bench: headroom plot in {}", png.display());
    } else {
        let _ = std::fs::remove_dir_all(&dir);
    }
    Ok(report)
}

/// The report as a table.
pub fn render(r: &HeadroomReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}; {:.0} s per rate, load {}, rt {}, model {}, wait {}",
        r.machine,
        r.duration_s,
        r.load,
        r.rt_settings.label(),
        r.model,
        r.wait
    );
    let _ = writeln!(
        s,
        "\n{:>6} {:<9} {:>7} {:>7} {:>7}   {:>23}   {:>23}   {:>8} {:>6}  per process (µs/tick)",
        "Hz",
        "transport",
        "ticks",
        "missed",
        "held",
        "e2e p50/p99/max (µs)",
        "lateness p50/p99/max",
        "CPU/tick",
        "share"
    );
    for row in &r.rows {
        let d3 = |d: &Dist| format!("{:.0}/{:.0}/{:.0}", d.p50, d.p99, d.max);
        let per: Vec<String> = row
            .cpu_per_tick_us
            .iter()
            .map(|(n, us)| format!("{n} {us:.1}"))
            .collect();
        let _ = writeln!(
            s,
            "{:>6} {:<9} {:>7} {:>7} {:>7}   {:>23}   {:>23}   {:>8.1} {:>5.1}%  {}",
            row.rate_hz,
            row.transport.to_string(),
            row.ticks,
            row.missed,
            row.held_up,
            d3(&row.e2e_us),
            d3(&row.tick_lateness_us),
            row.cpu_total_per_tick_us,
            row.cpu_share * 100.0,
            per.join(", ")
        );
        if !row.spin_us_per_tick.is_empty() {
            let spin: Vec<String> = row
                .spin_us_per_tick
                .iter()
                .map(|(n, us)| format!("{n} {us:.1}"))
                .collect();
            let _ = writeln!(s, "{:>6} polling per tick (µs): {}", "", spin.join(", "));
        }
    }
    if !r.ratios.is_empty() {
        let _ = writeln!(
            s,
            "\niceoryx2 / uds (below 1: iceoryx2 ahead)\n{:>6} {:>8} {:>8} {:>8} {:>12} {:>9}",
            "Hz", "e2e p50", "e2e p99", "e2e max", "late p99", "CPU/tick"
        );
        for q in &r.ratios {
            let _ = writeln!(
                s,
                "{:>6} {:>8.2} {:>8.2} {:>8.2} {:>12.2} {:>9.2}",
                q.rate_hz, q.e2e_p50, q.e2e_p99, q.e2e_max, q.lateness_p99, q.cpu_per_tick
            );
        }
    }
    s
}

/// Four panels against the rate (log scale), one line per transport: end to end p99, tick
/// lateness p99, CPU per tick (all processes) and missed ticks; into an RGB buffer of
/// [`learning::plot::SIZE`].
pub fn render_plot(r: &HeadroomReport, text: bool) -> Result<Vec<u8>, learning::plot::PlotError> {
    use plotters::prelude::*;
    let draw = |e: &dyn std::fmt::Display| learning::plot::PlotError::Draw(e.to_string());
    let (w, h) = learning::plot::SIZE;
    let mut buf = vec![0u8; (w as usize) * (h as usize) * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw(&e))?;
        let title = format!(
            "scl bench headroom: {:.0} s per rate, load {}, rt {}",
            r.duration_s,
            r.load,
            r.rt_settings.label()
        );
        let body = if text {
            root.titled(&title, ("sans-serif", 24))
                .map_err(|e| draw(&e))?
        } else {
            root.clone()
        };
        let panels = body.split_evenly((2, 2));
        type Pick = fn(&HeadroomRow) -> f64;
        let figures: [(&str, &str, Pick); 4] = [
            ("end to end p99", "µs", |row| row.e2e_us.p99),
            ("tick lateness p99", "µs", |row| row.tick_lateness_us.p99),
            ("CPU per tick, all processes", "µs", |row| {
                row.cpu_total_per_tick_us
            }),
            ("missed ticks", "ticks", |row| row.missed as f64),
        ];
        let (lo, hi) = rate_axis(r);
        let colours = [RGBColor(31, 119, 180), RGBColor(255, 127, 14)];
        let transports = transports_of(r);
        for (panel, (name, unit, pick)) in panels.iter().zip(figures) {
            let top = r.rows.iter().map(pick).fold(0.0, f64::max).max(1.0) * 1.15;
            let mut chart = ChartBuilder::on(panel);
            chart.margin(8);
            if text {
                chart
                    .caption(name, ("sans-serif", 18))
                    .x_label_area_size(30)
                    .y_label_area_size(50);
            }
            let mut chart = chart
                .build_cartesian_2d((lo..hi).log_scale(), 0.0..top)
                .map_err(|e| draw(&e))?;
            let mut mesh = chart.configure_mesh();
            if text {
                mesh.x_desc("rate (Hz)")
                    .y_desc(unit)
                    .x_label_formatter(&|v| format!("{v:.0}"));
            } else {
                mesh.disable_x_mesh().disable_y_mesh();
            }
            mesh.draw().map_err(|e| draw(&e))?;
            for (k, t) in transports.iter().enumerate() {
                let colour = colours[k % colours.len()];
                let points: Vec<(f64, f64)> = r
                    .rows
                    .iter()
                    .filter(|row| row.transport == *t)
                    .map(|row| (row.rate_hz, pick(row)))
                    .collect();
                let series = chart
                    .draw_series(LineSeries::new(
                        points.iter().copied(),
                        colour.stroke_width(2),
                    ))
                    .map_err(|e| draw(&e))?;
                if text {
                    series
                        .label(t.to_string())
                        .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], colour));
                }
                chart
                    .draw_series(points.iter().map(|p| Circle::new(*p, 3, colour.filled())))
                    .map_err(|e| draw(&e))?;
            }
            if text {
                chart
                    .configure_series_labels()
                    .border_style(BLACK)
                    .draw()
                    .map_err(|e| draw(&e))?;
            }
        }
        root.present().map_err(|e| draw(&e))?;
    }
    Ok(buf)
}

/// The plot's rate axis: the rates run, with a margin either side (10 to 2000 Hz without
/// rows).
fn rate_axis(r: &HeadroomReport) -> (f64, f64) {
    let (lo, hi) = r
        .rows
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), row| {
            (lo.min(row.rate_hz), hi.max(row.rate_hz))
        });
    if lo.is_finite() && hi > lo {
        (lo * 0.8, hi * 1.25)
    } else {
        (10.0, 2000.0)
    }
}

/// The transports of the rows, in order of first appearance.
fn transports_of(r: &HeadroomReport) -> Vec<Transport> {
    let mut transports: Vec<Transport> = Vec::new();
    for row in &r.rows {
        if !transports.contains(&row.transport) {
            transports.push(row.transport);
        }
    }
    transports
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(rate_hz: f64, transport: Transport, p99: f64) -> HeadroomRow {
        HeadroomRow {
            rate_hz,
            transport,
            ticks: 100,
            missed: 1,
            held_up: 1,
            e2e_us: Dist {
                p50: p99 / 2.0,
                p99,
                max: p99 * 2.0,
                ..Dist::default()
            },
            tick_lateness_us: Dist::default(),
            cpu_per_tick_us: vec![("bridge".into(), 10.0), ("safety".into(), 5.0)],
            cpu_total_per_tick_us: 15.0,
            cpu_share: 15.0 * rate_hz * 1e-6,
            process_cpu_share: vec![("bridge".into(), 10.0 * rate_hz * 1e-6)],
            spin_us_per_tick: vec![("mapper".into(), 2.5)],
        }
    }

    #[test]
    fn table_and_plot_of_every_rate() {
        let r = HeadroomReport {
            machine: Machine::detect(),
            duration_s: 1.0,
            rt_settings: RtSettings::ALL,
            load: 0,
            model: "bundled".into(),
            wait: scl_config::WaitStrategy::Predictive,
            rows: vec![
                row(40.0, Transport::Iceoryx2, 100.0),
                row(40.0, Transport::Uds, 200.0),
                row(1000.0, Transport::Iceoryx2, 50.0),
            ],
            ratios: vec![],
        };
        let t = render(&r);
        assert!(
            t.contains("1000") && t.contains("bridge 10.0") && t.contains("rt all"),
            "{t}"
        );
        let (w, h) = learning::plot::SIZE;
        assert_eq!(
            render_plot(&r, false).unwrap().len(),
            w as usize * h as usize * 3
        );
    }
}
