//! Figures of the experiments, drawn once per backend: a PNG (through an RGB buffer and the
//! `png` encoder) and an SVG. Text (titles, axis labels, legends) only when a system font
//! exists ([`crate::plot::load_font`]); the figures render without one.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::ExperimentError;

/// A figure that can draw itself on any plotters backend.
pub trait Figure {
    /// Draws on `root`; `text` says whether a font is available for labels.
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        text: bool,
    ) -> Result<(), String>;
}

/// Whether a font for labels was found (registered once per process).
pub fn text_available() -> bool {
    static TEXT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *TEXT.get_or_init(|| match crate::plot::load_font(None) {
        Ok(Some(_)) => true,
        Ok(None) => {
            tracing::warn!("no system font found: figures are drawn without text");
            false
        }
        Err(e) => {
            tracing::warn!("{e}: figures are drawn without text");
            false
        }
    })
}

/// Draws `fig` to `stem.png` and `stem.svg`, `size` pixels.
pub fn write(fig: &impl Figure, stem: &Path, size: (u32, u32)) -> Result<(), ExperimentError> {
    let text = text_available();
    let png_path = stem.with_extension("png");
    let svg_path = stem.with_extension("svg");
    let perr = |path: &Path, reason: String| ExperimentError::Plot {
        path: path.to_owned(),
        reason,
    };
    let (w, h) = size;
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE)
            .map_err(|e| perr(&png_path, e.to_string()))?;
        fig.draw(&root, text).map_err(|e| perr(&png_path, e))?;
        root.present().map_err(|e| perr(&png_path, e.to_string()))?;
    }
    let file = std::fs::File::create(&png_path).map_err(|source| ExperimentError::Write {
        path: png_path.clone(),
        source,
    })?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc
        .write_header()
        .map_err(|e| perr(&png_path, e.to_string()))?;
    writer
        .write_image_data(&buf)
        .map_err(|e| perr(&png_path, e.to_string()))?;
    writer
        .finish()
        .map_err(|e| perr(&png_path, e.to_string()))?;
    {
        let root = SVGBackend::new(&svg_path, (w, h)).into_drawing_area();
        root.fill(&WHITE)
            .map_err(|e| perr(&svg_path, e.to_string()))?;
        fig.draw(&root, text).map_err(|e| perr(&svg_path, e))?;
        root.present().map_err(|e| perr(&svg_path, e.to_string()))?;
    }
    Ok(())
}

/// Colours of the kinds / variants, in order.
pub const COLOURS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

/// Maps a plotters error to text.
pub fn err(e: impl std::fmt::Display) -> String {
    e.to_string()
}
