//! Figures as SVG documents (the paper's Fig. 2-6 and the service's own plots).
//!
//! Pure: no I/O, no async. Each builder turns already-loaded domain data into a [`Figure`]:
//! the SVG text plus the list of plotted series (name and colour), so callers and tests can
//! tell which polyline is which without parsing styles back. Rendering goes through `plotters`
//! with only its SVG backend; text uses its built-in metrics estimate (no font files).
//!
//! 3-D scenes are built first as a [`Scene`] of world-frame polylines and markers (robot base
//! frame, metres, `z` up) and drawn by [`render_scene`] from a [`View`] (azimuth/elevation).

mod scene;
mod series;
pub mod viewer;

pub use scene::{
    EllipsoidKind, GraspInput, MappingInput, Marker, Polyline, Scene, grasp_scene, mapping_scene,
    posture_scene, render_scene,
};
pub use series::{
    ExecutionSample, MAX_DRAWN, PcaPath, demonstration_figure, execution_figure, model_figure,
    trajectory_figure,
};

use plotters::style::RGBColor;

/// Width and height of every figure, pixels.
pub const SIZE: (u32, u32) = (800, 600);

/// Bad figure input: a parameter out of range or nothing to draw.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FigureError {
    #[error("{param} must be between {min} and {max}, got {value}")]
    OutOfRange {
        param: &'static str,
        value: f64,
        min: f64,
        max: f64,
    },
    #[error("{param} must hold {expected} values, got {got}")]
    WrongLength {
        param: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{what} has nothing to plot")]
    Empty { what: String },
    #[error("cannot draw the figure: {0}")]
    Render(String),
}

/// The camera of a 3-D figure: azimuth about the vertical axis and elevation above the
/// horizontal plane, degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
}

impl Default for View {
    fn default() -> Self {
        View {
            azimuth_deg: 35.0,
            elevation_deg: 20.0,
        }
    }
}

impl View {
    pub const AZIMUTH_RANGE: (f64, f64) = (-180.0, 180.0);
    pub const ELEVATION_RANGE: (f64, f64) = (-90.0, 90.0);

    /// A checked view; `None` keeps the default angle.
    pub fn new(azimuth_deg: Option<f64>, elevation_deg: Option<f64>) -> Result<View, FigureError> {
        let d = View::default();
        let az = azimuth_deg.unwrap_or(d.azimuth_deg);
        let el = elevation_deg.unwrap_or(d.elevation_deg);
        check_range("azimuth", az, View::AZIMUTH_RANGE)?;
        check_range("elevation", el, View::ELEVATION_RANGE)?;
        Ok(View {
            azimuth_deg: az,
            elevation_deg: el,
        })
    }
}

fn check_range(param: &'static str, value: f64, (min, max): (f64, f64)) -> Result<(), FigureError> {
    // `contains` is false for NaN, so NaN is rejected here too.
    if (min..=max).contains(&value) {
        Ok(())
    } else {
        Err(FigureError::OutOfRange {
            param,
            value,
            min,
            max,
        })
    }
}

/// One plotted series: its legend name and stroke colour (`#rrggbb`, as in the SVG).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SeriesInfo {
    pub name: String,
    pub color: String,
}

/// A rendered figure.
#[derive(Debug, Clone)]
pub struct Figure {
    pub svg: String,
    /// Every named series, in drawing order (a name appears once even when drawn as several
    /// polylines, e.g. the links of one posture).
    pub series: Vec<SeriesInfo>,
}

/// Colour as it appears in plotters' SVG output.
pub fn hex(c: RGBColor) -> String {
    format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2)
}

/// A qualitative palette (Tableau 10) for series that need telling apart.
pub const PALETTE: [RGBColor; 10] = [
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

pub(crate) fn render_err<E: std::fmt::Debug>(e: E) -> FigureError {
    FigureError::Render(format!("{e:?}"))
}

#[cfg(test)]
mod tests;
