//! Depth-image warping: the SC's deep frame moved to the FC's *current* view, so navigation
//! follows the FC's rate instead of the SC's (Springer 2008 §9.2, future work there; after
//! post-rendering 3D warping, Mark et al. 1997).
//!
//! # One FC frame with warping
//!
//! ```text
//! SC buffer (view V_s, every fragment) ──forward warp──► warped frame at V_now ──fill holes──┐
//! FC objects rendered at V_now ──────────────────────────────────────────────────── merge (deep)
//! ```
//!
//! **Forward warp.** Every SC fragment is unprojected at its pixel centre and window depth with
//! `(P V_s)⁻¹` and projected with `P V_now` — strata's reprojection transfer does exactly this
//! ([`strata_remote::reprojection::View::warp`]: eq. 5.10, then eq. 5.9), so no second copy of the
//! arithmetic lives here. Each fragment lands in one pixel; the runs are then sorted front to back.
//! Fragments keep the SC's **colour**: the headlight depends on the eye, so a warped fragment is
//! shaded as the SC saw it, not as the current view would (the audit counts what that costs).
//! Where the view did not change the warp is the identity, bit for bit.
//!
//! **Holes.** A pixel the warped frame leaves empty is a hole when the SC should have had
//! something there: a disocclusion (a surface the SC saw hidden), a crack (a surface magnified
//! so that one source pixel covers more than one target pixel), or the border the SC's view did
//! not reach. They are **filled by a back-checked splat**: an empty pixel takes the run of the
//! neighbour (of its 8) whose front fragment is *farthest* — what a disocclusion reveals is
//! behind — but only if that surface, carried back to the SC's view at the neighbour's depth,
//! lands on a pixel the SC covered. So a silhouette against the background is not grown into
//! the background, and with no view change nothing is filled. [`FILL_PASSES`] passes close holes
//! up to that many pixels wide. The border strip the SC never saw stays empty (a wider SC view
//! would cover it, at the SC's cost for every frame; see docs/mfr.md).
//!
//! Layout: the warped frame is an ordinary [`DeepFrame`] (offsets into depth, colour and object
//! columns), so the FC's deep composition and the audit take it unchanged.

use rayon::prelude::*;
use strata_core::{DeepFrame, DeepFrameError, Fragment, ObjectId};
use strata_remote::reprojection::View;
use strata_scene::Scene;

use crate::authority::ViewPose;
use crate::transfer::TransferBuffer;

/// Splat passes: holes up to this many pixels wide are filled.
pub const FILL_PASSES: usize = 2;

/// A pixel index no fragment lands in.
const NOWHERE: u32 = u32::MAX;

/// What one warp did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WarpInfo {
    /// The SC view the frame was warped from.
    pub from: Option<ViewPose>,
    /// Pixels the forward warp left empty (before filling), ascending.
    pub empty: Vec<u32>,
    /// Pixels the splat filled.
    pub filled: u64,
    /// Fragments that left the current view (or were behind the eye).
    pub lost: u64,
}

/// The reprojection views of `scene`'s objects seen through `pose` at `size`.
fn view_at(scene: &Scene, ids: &[ObjectId], pose: &ViewPose, (w, h): (u32, u32)) -> View {
    View::new(
        scene,
        ids,
        0,
        (w, h),
        pose.matrix(),
        scene.camera.projection(w, h),
    )
}

/// `frame` (seen through `from`) forward-warped to `to` and its holes filled; what it did.
/// Fails only if the filled frame would hold more than 2³² fragments.
pub fn warp_frame(
    scene: &Scene,
    frame: &DeepFrame,
    from: &ViewPose,
    to: &ViewPose,
) -> Result<(DeepFrame, WarpInfo), DeepFrameError> {
    let size = (frame.width(), frame.height());
    let ids: Vec<ObjectId> = scene.objects.iter().map(|o| o.id).collect();
    let (v_from, v_to) = (
        view_at(scene, &ids, from, size),
        view_at(scene, &ids, to, size),
    );
    let pixels = frame.offsets().len() - 1;
    // Every fragment's target pixel and moved fragment, in source order.
    let moved: Vec<(u32, Fragment)> = (0..pixels)
        .into_par_iter()
        .flat_map_iter(|p| {
            let (v_from, v_to) = (&v_from, &v_to);
            let run = frame.run(p);
            (0..run.len()).map(move |i| {
                run.get(i)
                    .and_then(|f| v_from.warp(v_to, p as u32, f))
                    .unwrap_or((NOWHERE, Fragment::default()))
            })
        })
        .collect();
    let lost = moved.iter().filter(|(p, _)| *p == NOWHERE).count() as u64;
    let mut warped = bucket(size, &moved)?;
    let empty: Vec<u32> = (0..pixels as u32)
        .filter(|&p| warped.run(p as usize).is_empty())
        .collect();
    let mut filled = 0u64;
    for _ in 0..FILL_PASSES {
        let fills = splats(&warped, frame, &v_from, &v_to);
        if fills.is_empty() {
            break;
        }
        filled += fills.len() as u64;
        warped = apply_fills(&warped, &fills)?;
    }
    let info = WarpInfo {
        from: Some(*from),
        empty,
        filled,
        lost,
    };
    Ok((warped, info))
}

/// The SC buffer warped to `to`: its frame and image replaced, its view set to `to` (so the FC
/// renders its objects there and the audit compares with the exact render there).
pub fn warp_buffer(
    scene: &Scene,
    sc: &TransferBuffer,
    to: &ViewPose,
) -> Result<(TransferBuffer, WarpInfo), DeepFrameError> {
    let (frame, info) = warp_frame(scene, &sc.frame, &sc.view, to)?;
    let image = frame.resolve(scene.background);
    let buffer = TransferBuffer {
        view: *to,
        frame,
        image,
        ..sc.clone()
    };
    Ok((buffer, info))
}

/// The fragments of `moved` gathered per target pixel (source order kept), runs sorted.
fn bucket((w, h): (u32, u32), moved: &[(u32, Fragment)]) -> Result<DeepFrame, DeepFrameError> {
    let pixels = w as usize * h as usize;
    let mut offsets = vec![0u32; pixels + 1];
    for &(p, _) in moved.iter().filter(|(p, _)| *p != NOWHERE) {
        offsets[p as usize + 1] += 1;
    }
    for p in 0..pixels {
        offsets[p + 1] += offsets[p];
    }
    let mut cursor = offsets[..pixels].to_vec();
    let mut out = vec![Fragment::default(); offsets[pixels] as usize];
    for &(p, f) in moved.iter().filter(|(p, _)| *p != NOWHERE) {
        let c = &mut cursor[p as usize];
        out[*c as usize] = f;
        *c += 1;
    }
    let mut counts = Vec::with_capacity(pixels);
    counts.extend(offsets.windows(2).map(|o| o[1] - o[0]));
    DeepFrame::build(w, h, &counts, |p, run| {
        run.extend_from_slice(&out[offsets[p] as usize..offsets[p + 1] as usize]);
    })
}

/// The holes of `warped` to fill this pass: `(empty pixel, neighbour whose run it takes)`.
fn splats(warped: &DeepFrame, source: &DeepFrame, v_from: &View, v_to: &View) -> Vec<(u32, u32)> {
    let (w, h) = (warped.width() as i64, warped.height() as i64);
    (0..(w * h) as usize)
        .into_par_iter()
        .filter(|&p| warped.run(p).is_empty())
        .filter_map(|p| {
            let (x, y) = (p as i64 % w, p as i64 / w);
            let mut best: Option<(u32, Fragment)> = None;
            for (dx, dy) in NEIGHBOURS {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= w || ny >= h {
                    continue;
                }
                let q = (ny * w + nx) as u32;
                if let Some(front) = warped.run(q as usize).get(0)
                    && best.is_none_or(|(_, b)| front.depth > b.depth)
                {
                    best = Some((q, front));
                }
            }
            let (q, front) = best?;
            // Back-check: that surface at this pixel, seen from the SC's view.
            let (s, _) = v_to.warp(v_from, p as u32, front)?;
            (!source.run(s as usize).is_empty()).then_some((p as u32, q))
        })
        .collect()
}

/// The 8 neighbours of a pixel.
const NEIGHBOURS: [(i64, i64); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

/// `frame` with each `(p, q)` of `fills` (ascending `p`) giving pixel `p` a copy of `q`'s run.
fn apply_fills(frame: &DeepFrame, fills: &[(u32, u32)]) -> Result<DeepFrame, DeepFrameError> {
    let pixels = frame.offsets().len() - 1;
    let mut source: Vec<u32> = (0..pixels as u32).collect();
    for &(p, q) in fills {
        source[p as usize] = q;
    }
    let total: u64 = source
        .iter()
        .map(|&q| frame.run(q as usize).len() as u64)
        .sum();
    if total > u64::from(u32::MAX) {
        return Err(DeepFrameError::TooManyFragments(total));
    }
    let counts: Vec<u32> = source
        .iter()
        .map(|&q| frame.run(q as usize).len() as u32)
        .collect();
    DeepFrame::build(frame.width(), frame.height(), &counts, |p, run| {
        run.extend(frame.run(source[p] as usize).iter());
    })
}

/// One warped frame measured against the exact render at the current view.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct WarpAudit {
    /// Pixels the forward warp left empty where the exact render shows an object the SC
    /// rendered (before filling).
    pub hole_pixels: u64,
    /// Of those, pixels still without one of the SC's objects after filling.
    pub holes_left: u64,
    /// Pixels the splat filled.
    pub filled_pixels: u64,
}

/// Holes of one warp: `warped` (after filling) and `info` against `reference`, the whole scene
/// rendered at the current view; `sc_objects` are the ids the SC rendered, sorted.
pub fn warp_audit(
    warped: &DeepFrame,
    info: &WarpInfo,
    reference: &DeepFrame,
    sc_objects: &[ObjectId],
) -> WarpAudit {
    let shows_sc = |p: usize| {
        reference
            .run(p)
            .iter()
            .any(|f| sc_objects.binary_search(&f.object).is_ok())
    };
    let holes: Vec<u32> = info
        .empty
        .iter()
        .copied()
        .filter(|&p| shows_sc(p as usize))
        .collect();
    let holes_left = holes
        .iter()
        .filter(|&&p| warped.run(p as usize).is_empty())
        .count() as u64;
    WarpAudit {
        hole_pixels: holes.len() as u64,
        holes_left,
        filled_pixels: info.filled,
    }
}

/// [`crate::simulate::run_virtual`] with warping: every FC frame warps the newest SC buffer to
/// the frame's own view (the current snapshot's) before the FC renders its objects there and
/// composes; [`crate::simulate::FcFrame::warp`] says what each warp did.
#[allow(
    clippy::too_many_arguments,
    reason = "the run's parameters, each documented"
)]
pub fn run_virtual_warped(
    scene: &Scene,
    trace: crate::trace::Trace,
    clock: crate::simulate::VirtualClock,
    migration: crate::simulate::Migration,
    composition: crate::compose::Composition,
    size: (u32, u32),
    fc_frames: u64,
    on_frame: impl FnMut(&crate::simulate::FcFrame),
) -> Result<(), crate::simulate::SimulateError> {
    crate::simulate::run_clients(
        scene,
        trace,
        clock,
        (migration, composition),
        size,
        fc_frames,
        true,
        on_frame,
    )
}
