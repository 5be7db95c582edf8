//! The font of the figures (`crate::figures`).
//!
//! PNG text needs a font; none is installed at a fixed path on the machines this runs on, so the
//! binary embeds DejaVu Sans (`assets/`, Bitstream Vera licence) and registers it once.

use plotters::prelude::FontStyle;
use std::sync::Once;

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

/// Registers the embedded font once (figures draw text in PNGs with it).
pub(crate) fn register_font() {
    REGISTER.call_once(|| {
        // The only way this fails is a corrupt embedded font, which a test would catch.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}
