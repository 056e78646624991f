//! `strata mfr`'s navigation figures: each frame against the exact render at the *current* view
//! (the normal audit compares with the view the frame composed through, which without `--warp`
//! is the SC buffer's older one), the holes depth-image warping opened and filled, and the
//! view-to-screen latency — from each camera move to the first frame showing the scene through
//! it. Frames whose view is the current one reuse the normal audit; others render one more
//! reference, so runs without navigation cost nothing more.

use anyhow::Result;
use serde_json::json;
use strata_core::ObjectId;
use strata_mfr::client::Client;
use strata_mfr::simulate::FcFrame;
use strata_mfr::trace::{Event, Trace};
use strata_mfr::warp::warp_audit;
use strata_mfr::{FrameAudit, audit};

/// Navigation totals over a run.
#[derive(Debug, Default)]
pub(super) struct ViewTotals {
    /// Frames whose view was not the current one.
    behind_frames: u64,
    /// Bad pixels against the exact render at the current view, summed, and their peak.
    bad_pixels: u64,
    max_bad_pixels: u64,
    /// RMSE against it, summed over frames.
    rmse: f64,
    /// Frames whose SC buffer was warped.
    warped_frames: u64,
    hole_pixels: u64,
    holes_left: u64,
    filled_pixels: u64,
    lost_fragments: u64,
    /// Per frame: when it was on screen and the trace time of the view it shows.
    shown: Vec<(f64, f64)>,
    frames: u64,
}

impl ViewTotals {
    /// Adds frame `f`, on screen at `shown_ms`, whose normal audit is `a`.
    pub(super) fn add(
        &mut self,
        scene: &strata_scene::Scene,
        reference: &mut Client,
        f: &FcFrame,
        a: &FrameAudit,
        shown_ms: f64,
    ) -> Result<()> {
        self.frames += 1;
        let (view, view_ms) = match (&f.sc, &f.warp) {
            (Some(sc), None) => (sc.view, sc.snapshot_t_ms),
            _ => (f.snapshot.view, f.t_ms),
        };
        self.shown.push((shown_ms, view_ms));
        let current = view == f.snapshot.view;
        if current && f.warp.is_none() {
            self.count_bad(a.bad_pixels, a.rmse);
            return Ok(());
        }
        let all: Vec<usize> = (0..scene.objects.len()).collect();
        let exact = reference.render(scene, &f.snapshot, &f.snapshot.view, &all)?;
        let (bad, rmse) = if current {
            (a.bad_pixels, a.rmse)
        } else {
            self.behind_frames += 1;
            let b = audit(&f.composed()?, &exact, scene.background);
            (b.bad_pixels, b.rmse)
        };
        self.count_bad(bad, rmse);
        if let (Some(info), Some(sc)) = (&f.warp, &f.sc) {
            let ids: Vec<ObjectId> = sc.rendered.iter().map(|&(id, _)| id).collect();
            let w = warp_audit(&sc.frame, info, &exact, &ids);
            self.warped_frames += 1;
            self.hole_pixels += w.hole_pixels;
            self.holes_left += w.holes_left;
            self.filled_pixels += w.filled_pixels;
            self.lost_fragments += info.lost;
        }
        Ok(())
    }

    fn count_bad(&mut self, bad: u64, rmse: f64) {
        self.rmse += rmse;
        self.bad_pixels += bad;
        self.max_bad_pixels = self.max_bad_pixels.max(bad);
    }

    /// The `view` object of summary.json.
    pub(super) fn json(&self, trace: &Trace, warp: bool) -> serde_json::Value {
        let mut latency: Vec<f64> = Vec::new();
        let mut not_shown = 0u64;
        for e in trace.events() {
            if !matches!(e.event, Event::View { .. }) {
                continue;
            }
            match self.shown.iter().find(|&&(_, v)| v >= e.t_ms) {
                Some(&(shown, _)) => latency.push(shown - e.t_ms),
                None => not_shown += 1,
            }
        }
        latency.sort_by(f64::total_cmp);
        let at = |q: f64| {
            (!latency.is_empty())
                .then(|| latency[((latency.len() - 1) as f64 * q).round() as usize])
        };
        let per_frame = |n: u64| n as f64 / self.frames.max(1) as f64;
        json!({
            "warp": warp,
            "frames_behind_current_view": self.behind_frames,
            "bad_pixels_vs_current_view": {
                "per_frame": per_frame(self.bad_pixels),
                "max": self.max_bad_pixels,
            },
            "rmse_vs_current_view": self.rmse / self.frames.max(1) as f64,
            "view_latency_ms": {
                "median": at(0.5),
                "p95": at(0.95),
                "max": latency.last(),
                "not_shown": not_shown,
            },
            "warped_frames": self.warped_frames,
            "hole_pixels_per_frame": per_frame(self.hole_pixels),
            "holes_left_per_frame": per_frame(self.holes_left),
            "filled_pixels_per_frame": per_frame(self.filled_pixels),
            "lost_fragments": self.lost_fragments,
        })
    }
}

/// One line for the text summary from the `view` object.
pub(super) fn view_text(v: &serde_json::Value) -> String {
    let l = &v["view_latency_ms"];
    format!(
        "view{}: bad pixels vs current view {:.1}/frame, RMSE {:.4}; view latency median {} ms, max {} ms; \
         holes {:.1}/frame, {:.1} left after filling",
        if v["warp"] == json!(true) {
            " (warped)"
        } else {
            ""
        },
        v["bad_pixels_vs_current_view"]["per_frame"]
            .as_f64()
            .unwrap_or(0.0),
        v["rmse_vs_current_view"].as_f64().unwrap_or(0.0),
        l["median"],
        l["max"],
        v["hole_pixels_per_frame"].as_f64().unwrap_or(0.0),
        v["holes_left_per_frame"].as_f64().unwrap_or(0.0),
    )
}
