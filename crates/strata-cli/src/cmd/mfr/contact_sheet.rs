//! Contact sheets: the FC frames around each select and release, side by side, as the seed's
//! figures 6.1–6.4 show them.
//!
//! One PNG per event, `event-NN-select.png` / `event-NN-release.png`, holding the frames from two
//! FC periods before the event until the SC has had time to catch up (at most 16 frames after),
//! left to right. Each frame is a column of three
//! parts:
//!
//! ```text
//! ┌──────────────┐  strip: green = frame equal to the reference, red = an artefact,
//! ├──────────────┤         yellow = the first frame that includes the event (white if clean)
//! │ frame shown  │  pixels the FC drew in colour, the SC's part greyed
//! ├──────────────┤
//! │ error map    │  the reference dimmed; bad pixels (> 2/255) red
//! └──────────────┘
//! ```
//!
//! Frames are scaled down by an integer factor (box filter) to at most [`CELL_WIDTH`] pixels
//! wide; only cells near an event are kept, so a long run costs no more memory than its events.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use strata_core::Rgb8Image;
use strata_core::metrics::DEFAULT_BAD_PIXEL_THRESHOLD;
use strata_mfr::simulate::FcFrame;
use strata_mfr::trace::{Button, Event, Trace};
use strata_mfr::{EventKind, FrameAudit};

/// Widest cell (pixels).
const CELL_WIDTH: u32 = 240;
/// FC periods shown before each event, and at most after it.
const BEFORE: f64 = 2.0;
const MOST_AFTER: f64 = 16.0;
/// Height of the status strip and the gap between cells (pixels).
const STRIP: u32 = 6;
const GAP: u32 = 4;

/// The sheets of one run, filled frame by frame.
pub(super) struct ContactSheets {
    period_ms: f64,
    after_ms: f64,
    events: Vec<Sheet>,
}

struct Sheet {
    kind: EventKind,
    t_ms: f64,
    /// The cells, in frame order.
    cells: Vec<Rgb8Image>,
    marked: bool,
}

impl ContactSheets {
    /// Sheets for every select and release of `trace`, for FC frames `period_ms` apart, showing
    /// `after_ms` after each event (at most 16 frames).
    pub(super) fn new(trace: &Trace, period_ms: f64, after_ms: f64) -> Self {
        let events = trace
            .events()
            .iter()
            .filter_map(|e| match e.event {
                Event::Button(Button::Down) => Some((EventKind::Select, e.t_ms)),
                Event::Button(Button::Up) => Some((EventKind::Release, e.t_ms)),
                _ => None,
            })
            .map(|(kind, t_ms)| Sheet {
                kind,
                t_ms,
                cells: Vec::new(),
                marked: false,
            })
            .collect();
        ContactSheets {
            period_ms,
            after_ms: after_ms.clamp(period_ms, MOST_AFTER * period_ms),
            events,
        }
    }

    /// Offers frame `f` (with its reference image and audit) to the sheets whose window holds it.
    pub(super) fn offer(&mut self, f: &FcFrame, reference: &Rgb8Image, audit: &FrameAudit) {
        let period = self.period_ms;
        for sheet in &mut self.events {
            let (from, to) = (
                sheet.t_ms - BEFORE * period - 1e-6,
                sheet.t_ms + self.after_ms,
            );
            if f.t_ms < from || f.t_ms > to {
                continue;
            }
            let first = !sheet.marked && f.t_ms >= sheet.t_ms;
            sheet.marked |= first;
            sheet
                .cells
                .push(cell(f, reference, audit.has_artefact(), first));
        }
    }

    /// Writes the sheets into `dir`; returns their paths.
    pub(super) fn write(&self, dir: &Path) -> Result<Vec<PathBuf>> {
        let mut written = Vec::new();
        for (n, sheet) in self.events.iter().enumerate() {
            if sheet.cells.is_empty() {
                continue;
            }
            let kind = match sheet.kind {
                EventKind::Select => "select",
                EventKind::Release => "release",
            };
            let path = dir.join(format!("event-{:02}-{kind}.png", n + 1));
            side_by_side(sheet.cells.iter())
                .write_png(&path)
                .with_context(|| format!("cannot write {}", path.display()))?;
            written.push(path);
        }
        Ok(written)
    }
}

/// One frame's column: strip, frame (SC part greyed), error map; scaled down.
fn cell(f: &FcFrame, reference: &Rgb8Image, artefact: bool, first: bool) -> Rgb8Image {
    let (w, h) = (f.image.width(), f.image.height());
    let scale = w.div_ceil(CELL_WIDTH).max(1);
    let (cw, ch) = (w.div_ceil(scale), h.div_ceil(scale));
    let strip = match (artefact, first) {
        (true, true) => [255, 200, 0],
        (false, true) => [255, 255, 255],
        (true, false) => [220, 30, 30],
        (false, false) => [40, 170, 60],
    };
    let mut out = Rgb8Image::filled(cw, STRIP + 2 * ch + GAP, [0, 0, 0]);
    for y in 0..STRIP {
        for x in 0..cw {
            put(&mut out, x, y, strip);
        }
    }
    let fc_drew = |x: u32, y: u32| f.fc.run_at(x, y).is_some_and(|r| !r.is_empty());
    for cy in 0..ch {
        for cx in 0..cw {
            let (mut shown, mut error, mut n) = ([0u32; 3], [0u32; 3], 0u32);
            for y in cy * scale..((cy + 1) * scale).min(h) {
                for x in cx * scale..((cx + 1) * scale).min(w) {
                    let (a, r) = (f.image.pixel(x, y), reference.pixel(x, y));
                    let s = if fc_drew(x, y) { a } else { grey(a) };
                    let bad = a
                        .iter()
                        .zip(r)
                        .any(|(&u, v)| u.abs_diff(v) > DEFAULT_BAD_PIXEL_THRESHOLD);
                    let e = if bad {
                        [255, 0, 0]
                    } else {
                        grey(r).map(|c| c / 2)
                    };
                    for c in 0..3 {
                        shown[c] += u32::from(s[c]);
                        error[c] += u32::from(e[c]);
                    }
                    n += 1;
                }
            }
            let avg = |v: [u32; 3]| v.map(|c| (c / n.max(1)) as u8);
            put(&mut out, cx, STRIP + cy, avg(shown));
            put(&mut out, cx, STRIP + ch + GAP + cy, avg(error));
        }
    }
    out
}

/// The colour as a light grey of its luminance.
fn grey([r, g, b]: [u8; 3]) -> [u8; 3] {
    let l = (u32::from(r) * 54 + u32::from(g) * 183 + u32::from(b) * 19) >> 8;
    let v = (96 + l * 5 / 8) as u8;
    [v; 3]
}

fn put(img: &mut Rgb8Image, x: u32, y: u32, rgb: [u8; 3]) {
    let i = ((y * img.width() + x) * 3) as usize;
    img.as_bytes_mut()[i..i + 3].copy_from_slice(&rgb);
}

/// Cells left to right with a gap between them.
fn side_by_side<'a>(cells: impl Iterator<Item = &'a Rgb8Image> + Clone) -> Rgb8Image {
    let width: u32 = cells.clone().map(|c| c.width() + GAP).sum::<u32>() - GAP;
    let height = cells.clone().map(Rgb8Image::height).max().unwrap_or(0);
    let mut out = Rgb8Image::filled(width.max(1), height.max(1), [0, 0, 0]);
    let mut x0 = 0;
    for c in cells {
        for y in 0..c.height() {
            for x in 0..c.width() {
                put(&mut out, x0 + x, y, c.pixel(x, y));
            }
        }
        x0 += c.width() + GAP;
    }
    out
}
