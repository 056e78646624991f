//! The audit: each composed frame against the single renderer's, in pixels and in objects.
//!
//! Per frame, with the reference being the whole scene rendered at once at the frame's snapshot
//! and through the view it composed with:
//!
//! - **bad pixels**: pixels whose resolved colour differs by more than 2/255 in some channel,
//!   and the RMSE over all channels;
//! - per pixel, the objects *visible* in a run — those with a fragment whose weight
//!   `α_i · Π_{j<i} (1 − α_j)` reaches 1/255 — in the composed frame and in the reference:
//!   - **ghost**: an object visible in the frame but not in the reference (it is drawn where it no
//!     longer is: the seed's selection artefact);
//!   - **hole**: an object visible in the reference but not in the frame (it is missing: the
//!     release artefact);
//!   - **blend**: the same objects visible but a bad pixel (their order or colours are wrong: the
//!     transparency artefact of colour-and-depth composition).

use strata_core::metrics::{DEFAULT_BAD_PIXEL_THRESHOLD, bad_pixels, rmse};
use strata_core::{DeepFrame, ObjectId, Rgb8Image, Run};
use strata_scene::Scene;

use crate::client::Client;
use crate::simulate::{FcFrame, SimulateError};

/// One frame's audit.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FrameAudit {
    /// Pixels off by more than 2/255 in some channel.
    pub bad_pixels: u64,
    /// Pixels showing an object the reference does not show there.
    pub ghost_pixels: u64,
    /// Pixels missing an object the reference shows there.
    pub hole_pixels: u64,
    /// Bad pixels showing the same objects as the reference.
    pub blend_pixels: u64,
    /// Root-mean-square error over the RGB channels, in [0, 1].
    pub rmse: f64,
}

impl FrameAudit {
    /// Whether the frame has any bad, ghost, hole or blend pixel.
    pub fn has_artefact(&self) -> bool {
        self.bad_pixels + self.ghost_pixels + self.hole_pixels + self.blend_pixels > 0
    }
}

/// The smallest weight that counts an object as visible (1/255).
const VISIBLE: f32 = 1.0 / 255.0;

/// Most distinct visible objects tracked per pixel (more are not told apart).
const MAX_IDS: usize = 32;

/// The objects visible in a run, sorted, deduplicated, into `out`.
fn visible(run: Run<'_>, out: &mut Vec<ObjectId>) {
    out.clear();
    let mut t = 1.0f32;
    for f in run.iter() {
        let a = f32::from(f.color.alpha()) / 255.0;
        if t * a >= VISIBLE && out.len() < MAX_IDS {
            out.push(f.object);
        }
        t *= 1.0 - a;
        if t < VISIBLE {
            break;
        }
    }
    out.sort_unstable();
    out.dedup();
}

/// Audits `frame` against `reference` (same size), resolved onto `background`.
pub fn audit(frame: &DeepFrame, reference: &DeepFrame, background: [f32; 3]) -> FrameAudit {
    let (a, b) = (frame.resolve(background), reference.resolve(background));
    let threshold = DEFAULT_BAD_PIXEL_THRESHOLD;
    let mut out = FrameAudit {
        bad_pixels: bad_pixels(&a, &b, threshold).map_or(0, |b| b.count),
        rmse: rmse(&a, &b).unwrap_or(1.0),
        ..FrameAudit::default()
    };
    if frame.width() != reference.width() || frame.height() != reference.height() {
        return out;
    }
    let (mut mine, mut theirs) = (Vec::new(), Vec::new());
    let width = frame.width();
    for p in 0..frame.offsets().len() - 1 {
        visible(frame.run(p), &mut mine);
        visible(reference.run(p), &mut theirs);
        let ghost = mine.iter().any(|o| theirs.binary_search(o).is_err());
        let hole = theirs.iter().any(|o| mine.binary_search(o).is_err());
        out.ghost_pixels += u64::from(ghost);
        out.hole_pixels += u64::from(hole);
        if !ghost && !hole {
            let (x, y) = ((p as u32) % width, (p as u32) / width);
            let (pa, pb) = (a.pixel(x, y), b.pixel(x, y));
            let off = pa.iter().zip(pb).any(|(&u, v)| u.abs_diff(v) > threshold);
            out.blend_pixels += u64::from(off);
        }
    }
    out
}

/// Audits an FC frame against the whole scene rendered at once by `reference` (a client of the
/// frame's size), at the frame's snapshot and through the view it composed with; also returns
/// the reference's image.
pub fn audit_fc_frame(
    scene: &Scene,
    reference: &mut Client,
    frame: &FcFrame,
) -> Result<(FrameAudit, Rgb8Image), SimulateError> {
    let view = frame.sc.as_ref().map_or(frame.snapshot.view, |sc| sc.view);
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    let r = reference.render(scene, &frame.snapshot, &view, &all)?;
    Ok((
        audit(&frame.composed()?, &r, scene.background),
        r.resolve(scene.background),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::{Fragment, Rgba8};

    fn frag(depth: f32, object: u32, a: u8) -> Fragment {
        Fragment {
            depth,
            color: Rgba8([(object * 60) as u8, 100, 255 - (object * 50) as u8, a]),
            object: ObjectId(object),
        }
    }

    #[test]
    fn ghosts_holes_and_blends_are_told_apart() {
        let reference = DeepFrame::from_pixel_lists(
            3,
            1,
            &[
                vec![frag(0.5, 1, 128)],
                vec![frag(0.5, 2, 128)],
                vec![frag(0.2, 3, 128), frag(0.4, 4, 200)],
            ],
        )
        .expect("frame");
        let frame = DeepFrame::from_pixel_lists(
            3,
            1,
            &[
                // An extra object in front: a ghost.
                vec![frag(0.1, 9, 128), frag(0.5, 1, 128)],
                // The object is missing: a hole.
                vec![],
                // The same objects in the wrong order: a blend.
                vec![frag(0.2, 4, 200), frag(0.4, 3, 128)],
            ],
        )
        .expect("frame");
        let a = audit(&frame, &reference, [1.0; 3]);
        assert_eq!(a.ghost_pixels, 1);
        assert_eq!(a.hole_pixels, 1);
        assert_eq!(a.blend_pixels, 1);
        assert_eq!(a.bad_pixels, 3);
        assert_eq!(
            audit(&reference, &reference, [1.0; 3]),
            FrameAudit::default()
        );
    }
}
