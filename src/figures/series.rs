//! 2-D figures over time or in PCA space: demonstrations, trajectories, executions, models.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{Figure, FigureError, PALETTE, SIZE, SeriesInfo, hex, render_err};
use crate::human::HumanFrame;
use crate::motion::TrajectoryPoint;

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// Most points drawn per line over time: a figure is 800 px wide, so more points only make the
/// SVG bigger and slower (a 10-minute trajectory has 60 000).
pub const MAX_DRAWN: usize = 1000;

/// At most [`MAX_DRAWN`] items, evenly spaced, always including the first and the last.
fn thinned<T>(items: &[T]) -> impl Iterator<Item = &T> {
    let n = items.len();
    let m = n.min(MAX_DRAWN);
    // i (n-1) / (m-1) is strictly increasing in i when n >= m, and ends at n - 1.
    (0..m).map(move |i| {
        if m < 2 {
            &items[i]
        } else {
            &items[i * (n - 1) / (m - 1)]
        }
    })
}

/// `lo..hi` padded by 5 % (and widened when flat, so a constant series still has an axis).
fn padded(lo: f64, hi: f64) -> std::ops::Range<f64> {
    if !(lo.is_finite() && hi.is_finite()) || lo > hi {
        return 0.0..1.0;
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    lo - pad..hi + pad
}

fn extent(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        })
}

/// One 2-D line series of a panel.
struct Line {
    name: String,
    color: RGBColor,
    dashed: bool,
    points: Vec<(f64, f64)>,
}

/// A panel of line series with labelled axes and a legend.
fn draw_panel(
    area: &Area<'_>,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    lines: &[Line],
    series: &mut Vec<SeriesInfo>,
) -> Result<(), FigureError> {
    let (x0, x1) = extent(lines.iter().flat_map(|l| l.points.iter().map(|p| p.0)));
    let (y0, y1) = extent(lines.iter().flat_map(|l| l.points.iter().map(|p| p.1)));
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(55)
        .build_cartesian_2d(padded(x0, x1), padded(y0, y1))
        .map_err(render_err)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .light_line_style(RGBColor(240, 240, 240))
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(render_err)?;
    for l in lines {
        let style = ShapeStyle::from(&l.color).stroke_width(2);
        let anno = if l.dashed {
            chart
                .draw_series(DashedLineSeries::new(l.points.iter().copied(), 6, 4, style))
                .map_err(render_err)?
        } else {
            chart
                .draw_series(LineSeries::new(l.points.iter().copied(), style))
                .map_err(render_err)?
        };
        if !series.iter().any(|s| s.name == l.name) {
            series.push(SeriesInfo {
                name: l.name.clone(),
                color: hex(l.color),
            });
            let color = l.color;
            anno.label(l.name.clone()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
            });
        }
    }
    if lines.len() > 1 {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font(("sans-serif", 11))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .draw()
            .map_err(render_err)?;
    }
    Ok(())
}

fn finish(svg: String, series: Vec<SeriesInfo>) -> Figure {
    Figure { svg, series }
}

/// Wrist speed (central differences of the wrist position) and grip aperture (thumb tip to
/// index tip distance) over time: the two classic reach-to-grasp profiles.
pub fn demonstration_figure(title: &str, frames: &[HumanFrame]) -> Result<Figure, FigureError> {
    if frames.len() < 3 {
        return Err(FigureError::Empty {
            what: format!("a demonstration with {} frames", frames.len()),
        });
    }
    let n = frames.len();
    let pos = |k: usize| frames[k].wrist.translation.vector;
    let speed: Vec<(f64, f64)> = (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            let dt = frames[b].t - frames[a].t;
            let v = if dt > 0.0 {
                (pos(b) - pos(a)).norm() / dt
            } else {
                0.0
            };
            (frames[k].t, v)
        })
        .collect();
    let aperture: Vec<(f64, f64)> = frames
        .iter()
        .map(|f| {
            let d = f.fingertips[0].translation.vector - f.fingertips[1].translation.vector;
            (f.t, d.norm() * 100.0)
        })
        .collect();
    let mut svg = String::new();
    let mut series = Vec::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(render_err)?;
        let root = root.titled(title, ("sans-serif", 20)).map_err(render_err)?;
        let panels = root.split_evenly((2, 1));
        draw_panel(
            &panels[0],
            "wrist speed",
            "t (s)",
            "speed (m/s)",
            &[Line {
                name: "wrist speed".into(),
                color: PALETTE[0],
                dashed: false,
                points: speed,
            }],
            &mut series,
        )?;
        draw_panel(
            &panels[1],
            "grip aperture (thumb tip to index tip)",
            "t (s)",
            "aperture (cm)",
            &[Line {
                name: "grip aperture".into(),
                color: PALETTE[1],
                dashed: false,
                points: aperture,
            }],
            &mut series,
        )?;
        root.present().map_err(render_err)?;
    }
    Ok(finish(svg, series))
}

fn check_points(
    joint_names: &[String],
    points: &[TrajectoryPoint],
    what: &str,
) -> Result<(), FigureError> {
    if points.is_empty() || joint_names.is_empty() {
        return Err(FigureError::Empty { what: what.into() });
    }
    if let Some(p) = points
        .iter()
        .find(|p| p.positions.len() != joint_names.len())
    {
        return Err(FigureError::WrongLength {
            param: "positions",
            expected: joint_names.len(),
            got: p.positions.len(),
        });
    }
    Ok(())
}

/// Joint positions over time, one line per joint.
pub fn trajectory_figure(
    title: &str,
    joint_names: &[String],
    points: &[TrajectoryPoint],
) -> Result<Figure, FigureError> {
    check_points(joint_names, points, "the trajectory")?;
    let lines: Vec<Line> = joint_names
        .iter()
        .enumerate()
        .map(|(j, name)| Line {
            name: name.clone(),
            color: PALETTE[j % PALETTE.len()],
            dashed: false,
            points: thinned(points).map(|p| (p.t, p.positions[j])).collect(),
        })
        .collect();
    let mut svg = String::new();
    let mut series = Vec::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(render_err)?;
        draw_panel(
            &root,
            title,
            "t (s)",
            "joint position (rad)",
            &lines,
            &mut series,
        )?;
        root.present().map_err(render_err)?;
    }
    Ok(finish(svg, series))
}

/// One measured state of an execution.
#[derive(Debug, Clone, PartialEq)]
pub struct ExecutionSample {
    pub t: f64,
    pub positions: Vec<f64>,
}

/// Planned (dashed) vs measured (solid) joint positions over time, same colour per joint; with
/// no planned points (closed loop) the measured ones alone. Each line draws at most
/// [`MAX_DRAWN`] points.
pub fn execution_figure(
    title: &str,
    joint_names: &[String],
    planned: &[TrajectoryPoint],
    measured: &[ExecutionSample],
) -> Result<Figure, FigureError> {
    if !planned.is_empty() {
        check_points(joint_names, planned, "the planned trajectory")?;
    }
    if let Some(s) = measured
        .iter()
        .find(|s| s.positions.len() != joint_names.len())
    {
        return Err(FigureError::WrongLength {
            param: "measured positions",
            expected: joint_names.len(),
            got: s.positions.len(),
        });
    }
    if planned.is_empty() && measured.is_empty() {
        return Err(FigureError::Empty {
            what: "the execution".into(),
        });
    }
    let mut lines = Vec::new();
    for (j, name) in joint_names.iter().enumerate() {
        let color = PALETTE[j % PALETTE.len()];
        if !planned.is_empty() {
            lines.push(Line {
                name: format!("{name} planned"),
                color,
                dashed: true,
                points: thinned(planned).map(|p| (p.t, p.positions[j])).collect(),
            });
        }
        if !measured.is_empty() {
            lines.push(Line {
                name: format!("{name} measured"),
                color,
                dashed: false,
                points: thinned(measured).map(|s| (s.t, s.positions[j])).collect(),
            });
        }
    }
    let mut svg = String::new();
    let mut series = Vec::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(render_err)?;
        draw_panel(
            &root,
            title,
            "t (s)",
            "joint position (rad)",
            &lines,
            &mut series,
        )?;
        root.present().map_err(render_err)?;
    }
    Ok(finish(svg, series))
}

/// A path in the first two PCA coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct PcaPath {
    /// Demonstrated (mapped) or generated by the model.
    pub generated: bool,
    pub points: Vec<(f64, f64)>,
}

/// Explained variance per principal component (bars, with the cumulative line) and
/// demonstrated vs generated paths in the plane of the first two components.
pub fn model_figure(
    title: &str,
    explained_variance: &[f64],
    paths: &[PcaPath],
) -> Result<Figure, FigureError> {
    if explained_variance.is_empty() {
        return Err(FigureError::Empty {
            what: "the model's explained variance".into(),
        });
    }
    let mut svg = String::new();
    let mut series = Vec::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(render_err)?;
        let root = root.titled(title, ("sans-serif", 20)).map_err(render_err)?;
        let panels = root.split_evenly((1, 2));
        let n = explained_variance.len();
        let mut chart = ChartBuilder::on(&panels[0])
            .caption("explained variance per component", ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(0.5..n as f64 + 0.5, 0.0..1.05)
            .map_err(render_err)?;
        chart
            .configure_mesh()
            .x_desc("component")
            .y_desc("fraction of variance")
            .x_labels(n.min(10))
            .light_line_style(RGBColor(240, 240, 240))
            .label_style(("sans-serif", 12))
            .draw()
            .map_err(render_err)?;
        let bars = PALETTE[0];
        chart
            .draw_series(explained_variance.iter().enumerate().map(|(k, v)| {
                let x = k as f64 + 1.0;
                Rectangle::new([(x - 0.35, 0.0), (x + 0.35, *v)], bars.filled())
            }))
            .map_err(render_err)?;
        series.push(SeriesInfo {
            name: "explained variance".into(),
            color: hex(bars),
        });
        let mut cum = 0.0;
        let cumulative: Vec<(f64, f64)> = explained_variance
            .iter()
            .enumerate()
            .map(|(k, v)| {
                cum += v;
                (k as f64 + 1.0, cum)
            })
            .collect();
        let line = PALETTE[1];
        chart
            .draw_series(LineSeries::new(cumulative, line.stroke_width(2)))
            .map_err(render_err)?;
        series.push(SeriesInfo {
            name: "cumulative".into(),
            color: hex(line),
        });

        let demo = RGBColor(127, 127, 127);
        let generated = PALETTE[3];
        let lines: Vec<Line> = paths
            .iter()
            .map(|p| Line {
                name: if p.generated {
                    "generated".into()
                } else {
                    "demonstrated".into()
                },
                color: if p.generated { generated } else { demo },
                dashed: false,
                points: p.points.clone(),
            })
            .collect();
        if !lines.is_empty() {
            draw_panel(
                &panels[1],
                "paths in PCA space",
                "y1",
                "y2",
                &lines,
                &mut series,
            )?;
        }
        root.present().map_err(render_err)?;
    }
    Ok(finish(svg, series))
}
