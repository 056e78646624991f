//! What the display measures: one [`FrameStats`] per composed frame (one [`NodeFrame`] per node
//! in it), and the [`Summary`] of a run — the figures of seed 000's Tables A.1–A.2 and
//! Figures 6.1–6.3.
//!
//! Times are wall-clock milliseconds. "transfer" is how long a message's body took to arrive
//! after its first bytes did: on loopback a memory copy, on a shaped link the wire time.

use serde::Serialize;

/// How one node's contribution to a frame went.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct NodeFrame {
    /// The node's address.
    pub node: String,
    /// `ok`, `held` (its last good copy was used), `dropped` (left out) or `down`.
    pub status: &'static str,
    /// Encoded bytes received for this frame (delta and fixup messages).
    pub bytes: u64,
    /// The same fragments in the seed layout (4 bytes per pixel + 12 per fragment).
    pub raw_bytes: u64,
    /// Fragments in the node's whole frame.
    pub fragments_rendered: u64,
    /// Fragments the node sent.
    pub fragments_sent: u64,
    /// Reprojection: held fragments the node removed by position (not counted in
    /// `fragments_sent`: a removal is a position of a byte or two, not a fragment — the seed sent
    /// each as a flagged fragment).
    pub removals: u64,
    /// Node: clear + capture + DeepFrame export.
    pub render_ms: f64,
    /// Node: the transfer method's choice.
    pub select_ms: f64,
    /// Node: encoding.
    pub encode_ms: f64,
    /// Display: receiving the message bodies.
    pub transfer_ms: f64,
    /// Display: decoding.
    pub decode_ms: f64,
    /// Difference: pixels fixed up after the delta (shared with another node).
    pub fixup_pixels: u64,
}

/// One composed frame.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct FrameStats {
    /// Animation frame.
    pub frame: u64,
    /// Per node, in `--nodes` order.
    pub nodes: Vec<NodeFrame>,
    /// Applying the received runs to the display's copies.
    pub merge_ms: f64,
    /// Merging the copies per pixel and resolving.
    pub resolve_ms: f64,
    /// Time since the previous frame was composed (0 for the first).
    pub interval_ms: f64,
    /// Fragments the display composited.
    pub fragments_displayed: u64,
    /// Bad pixels against the exact local render, when checked.
    pub bad_pixels: Option<u64>,
}

impl FrameStats {
    /// Encoded bytes over all nodes.
    pub fn bytes(&self) -> u64 {
        self.nodes.iter().map(|n| n.bytes).sum()
    }

    /// Seed-layout bytes over all nodes.
    pub fn raw_bytes(&self) -> u64 {
        self.nodes.iter().map(|n| n.raw_bytes).sum()
    }

    /// Fragments sent over all nodes.
    pub fn fragments_sent(&self) -> u64 {
        self.nodes.iter().map(|n| n.fragments_sent).sum()
    }

    /// Removals over all nodes.
    pub fn removals(&self) -> u64 {
        self.nodes.iter().map(|n| n.removals).sum()
    }

    /// Fragments rendered over all nodes.
    pub fn fragments_rendered(&self) -> u64 {
        self.nodes.iter().map(|n| n.fragments_rendered).sum()
    }
}

/// Something that happened to a node during a run.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct NodeIncident {
    /// The frame being composed when it happened.
    pub frame: u64,
    /// The node's address.
    pub node: String,
    /// What happened, for a person.
    pub what: String,
}

/// The median of the finite values of `v` (0 when there are none); see
/// [`strata_core::stats::median`].
pub fn median(v: Vec<f64>) -> f64 {
    strata_core::stats::median(v).unwrap_or(0.0)
}

/// A whole run.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Summary {
    /// Scene name.
    pub scene: String,
    /// Frame size.
    pub width: u32,
    /// Frame size.
    pub height: u32,
    /// Transfer method and its options, as given.
    pub transfer: String,
    /// Codec.
    pub codec: String,
    /// Node addresses.
    pub nodes: Vec<String>,
    /// Frames composed.
    pub frames: usize,
    /// Frames per second from the first composed frame to the last.
    pub display_fps: f64,
    /// Median encoded bytes per frame (all nodes).
    pub bytes_per_frame: f64,
    /// Median seed-layout bytes per frame of what was sent.
    pub raw_bytes_per_frame: f64,
    /// Encoded bytes over 16 bytes per rendered fragment, summed over the run.
    pub bytes_vs_16n: f64,
    /// Fragments sent over fragments rendered, summed over the run.
    pub fragments_sent_share: f64,
    /// Same, without the first frame (what the difference transfer saves in steady state).
    pub fragments_sent_share_after_first: f64,
    /// Reprojection: removals over fragments rendered, without the first frame (the seed's
    /// difference lists counted each removal as a fragment).
    pub removals_share_after_first: f64,
    /// Medians per node-frame, ms.
    pub render_ms: f64,
    /// Median.
    pub select_ms: f64,
    /// Median.
    pub encode_ms: f64,
    /// Median of the slowest node's transfer per frame.
    pub transfer_ms: f64,
    /// Median.
    pub decode_ms: f64,
    /// Median.
    pub merge_ms: f64,
    /// Median.
    pub resolve_ms: f64,
    /// Median interval between composed frames.
    pub interval_ms: f64,
    /// Frames checked against the exact local render.
    pub checked_frames: usize,
    /// Frames with at least one bad pixel.
    pub frames_with_bad_pixels: usize,
    /// Most bad pixels in one frame.
    pub max_bad_pixels: u64,
    /// Bad-pixel threshold (max channel difference above it), as DESIGN §2.
    pub bad_pixel_threshold: u8,
    /// Faults and reconnections.
    pub incidents: Vec<NodeIncident>,
    /// Every frame.
    pub per_frame: Vec<FrameStats>,
}

impl Summary {
    /// Fills the figures from `per_frame`.
    #[allow(
        clippy::too_many_arguments,
        reason = "one call site, every field named there"
    )]
    pub fn new(
        scene: String,
        width: u32,
        height: u32,
        transfer: String,
        codec: String,
        nodes: Vec<String>,
        elapsed_s: f64,
        bad_pixel_threshold: u8,
        incidents: Vec<NodeIncident>,
        per_frame: Vec<FrameStats>,
    ) -> Self {
        let node_frames = || {
            per_frame
                .iter()
                .flat_map(|f| f.nodes.iter())
                .filter(|n| n.status == "ok")
        };
        let frames = per_frame.len();
        let sum = |f: &dyn Fn(&FrameStats) -> u64, skip: usize| -> u64 {
            per_frame.iter().skip(skip).map(f).sum()
        };
        let ratio = |a: u64, b: u64| if b == 0 { 0.0 } else { a as f64 / b as f64 };
        let checked: Vec<u64> = per_frame.iter().filter_map(|f| f.bad_pixels).collect();
        Summary {
            scene,
            width,
            height,
            transfer,
            codec,
            nodes,
            frames,
            display_fps: if frames > 1 && elapsed_s > 0.0 {
                (frames - 1) as f64 / elapsed_s
            } else {
                0.0
            },
            bytes_per_frame: median(per_frame.iter().map(|f| f.bytes() as f64).collect()),
            raw_bytes_per_frame: median(per_frame.iter().map(|f| f.raw_bytes() as f64).collect()),
            bytes_vs_16n: ratio(
                sum(&|f| f.bytes(), 0),
                16 * sum(&|f| f.fragments_rendered(), 0),
            ),
            fragments_sent_share: ratio(
                sum(&|f| f.fragments_sent(), 0),
                sum(&|f| f.fragments_rendered(), 0),
            ),
            fragments_sent_share_after_first: ratio(
                sum(&|f| f.fragments_sent(), 1),
                sum(&|f| f.fragments_rendered(), 1),
            ),
            removals_share_after_first: ratio(
                sum(&|f| f.removals(), 1),
                sum(&|f| f.fragments_rendered(), 1),
            ),
            render_ms: median(node_frames().map(|n| n.render_ms).collect()),
            select_ms: median(node_frames().map(|n| n.select_ms).collect()),
            encode_ms: median(node_frames().map(|n| n.encode_ms).collect()),
            transfer_ms: median(
                per_frame
                    .iter()
                    .map(|f| f.nodes.iter().map(|n| n.transfer_ms).fold(0.0, f64::max))
                    .collect(),
            ),
            decode_ms: median(node_frames().map(|n| n.decode_ms).collect()),
            merge_ms: median(per_frame.iter().map(|f| f.merge_ms).collect()),
            resolve_ms: median(per_frame.iter().map(|f| f.resolve_ms).collect()),
            interval_ms: median(per_frame.iter().skip(1).map(|f| f.interval_ms).collect()),
            checked_frames: checked.len(),
            frames_with_bad_pixels: checked.iter().filter(|&&b| b > 0).count(),
            max_bad_pixels: checked.iter().copied().max().unwrap_or(0),
            bad_pixel_threshold,
            incidents,
            per_frame,
        }
    }

    /// The summary as pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// A table for a person.
    pub fn to_table(&self) -> String {
        let mb = |b: f64| b / 1e6;
        let mut s = String::new();
        use std::fmt::Write;
        let _ = writeln!(
            s,
            "display: {} at {}x{}, transfer {}, codec {}, {} node(s), {} frame(s)",
            self.scene,
            self.width,
            self.height,
            self.transfer,
            self.codec,
            self.nodes.len(),
            self.frames
        );
        let _ = writeln!(
            s,
            "  display rate      {:8.2} fps   (median interval {:.1} ms)",
            self.display_fps, self.interval_ms
        );
        let _ = writeln!(
            s,
            "  bytes per frame   {:8.3} MB encoded, {:.3} MB in the seed layout; {:.1}% of 16 B x fragments rendered",
            mb(self.bytes_per_frame),
            mb(self.raw_bytes_per_frame),
            100.0 * self.bytes_vs_16n
        );
        let _ = writeln!(
            s,
            "  fragments sent    {:8.1}% of rendered ({:.1}% after the first frame)",
            100.0 * self.fragments_sent_share,
            100.0 * self.fragments_sent_share_after_first
        );
        if self.removals_share_after_first > 0.0 {
            let _ = writeln!(
                s,
                "  removals          {:8.1}% of rendered after the first frame (positions, not fragments)",
                100.0 * self.removals_share_after_first
            );
        }
        let _ = writeln!(
            s,
            "  node ms (median)  render {:.1}, select {:.1}, encode {:.1}",
            self.render_ms, self.select_ms, self.encode_ms
        );
        let _ = writeln!(
            s,
            "  display ms        transfer {:.1}, decode {:.1}, merge {:.1}, resolve {:.1}",
            self.transfer_ms, self.decode_ms, self.merge_ms, self.resolve_ms
        );
        if self.checked_frames > 0 {
            let _ = writeln!(
                s,
                "  exactness         {} of {} checked frame(s) with bad pixels (> {}/255), at most {} in a frame",
                self.frames_with_bad_pixels,
                self.checked_frames,
                self.bad_pixel_threshold,
                self.max_bad_pixels
            );
        }
        for i in &self.incidents {
            let _ = writeln!(s, "  frame {:>5}: node {}: {}", i.frame, i.node, i.what);
        }
        s
    }
}
