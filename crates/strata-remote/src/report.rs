//! What the display measures: one [`FrameStats`] per composed frame (one [`NodeFrame`] per node
//! in it), and the [`Summary`] of a run — the figures of Jähne 2014's Tables A.1–A.2 and
//! Figures 6.1–6.3.
//!
//! Rates, bytes and times are figures of the *delivered* frames only — frames to which at least
//! one node contributed its current fragments — so a run in which no node delivered anything
//! has no figures at all rather than a rate of empty frames; [`Outcome`] says whether every node
//! delivered every frame and [`NodeShortfall`] which did not.
//!
//! Times are wall-clock milliseconds. "transfer" is how long a message's body took to arrive
//! after its first bytes did: on loopback a memory copy, on a shaped link the wire time.

use serde::Serialize;

/// Whether a node's frame made it into a composed frame (`ok`, `held`, `dropped` in JSON).
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum NodeStatus {
    /// The node delivered this frame and it was composed.
    Ok,
    /// The node's frame was missing; its last good copy was composed (`--on-fault hold`).
    Held,
    /// The node's frame was missing; the frame was composed without it (`--on-fault drop`).
    #[default]
    Dropped,
}

impl NodeStatus {
    /// Whether the node delivered the frame.
    pub fn delivered(self) -> bool {
        self == NodeStatus::Ok
    }

    /// The status as the summary spells it.
    pub fn name(self) -> &'static str {
        match self {
            NodeStatus::Ok => "ok",
            NodeStatus::Held => "held",
            NodeStatus::Dropped => "dropped",
        }
    }
}

/// How one node's contribution to a frame went.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct NodeFrame {
    /// The node's address.
    pub node: String,
    /// Whether its frame arrived, or what was composed instead.
    pub status: NodeStatus,
    /// Encoded bytes received for this frame (delta and fixup messages).
    pub bytes: u64,
    /// The same fragments in the thesis layout (4 bytes per pixel + 12 per fragment).
    pub raw_bytes: u64,
    /// Fragments in the node's whole frame.
    pub fragments_rendered: u64,
    /// Fragments the node sent.
    pub fragments_sent: u64,
    /// Reprojection: held fragments the node removed by position (not counted in
    /// `fragments_sent`: a removal is a position of a byte or two, not a fragment — the thesis sent
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

/// How a run went, judged by what the nodes delivered.
#[derive(Clone, Copy, Debug, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Outcome {
    /// Every node delivered every frame.
    Complete,
    /// Some frames were delivered, but some node missed some or all of them (it was lost,
    /// stalled, failed or left out): those frames were composed without its current fragments.
    Degraded,
    /// No node delivered any frame: nothing was displayed.
    NothingDelivered,
}

/// A node that missed frames during a run.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct NodeShortfall {
    /// The node's address.
    pub node: String,
    /// Frames it delivered.
    pub delivered: usize,
    /// Frames composed without its frame.
    pub missed: usize,
    /// The first frame it missed.
    pub first_missed: u64,
    /// The last frame it delivered, if any.
    pub last_delivered: Option<u64>,
    /// What was composed instead: its last good copy (`held`) or nothing (`dropped`).
    pub composed_as: NodeStatus,
}

/// The figures of the frames some node delivered (a run that delivered nothing has none).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Figures {
    /// Delivered frames per second, from the first delivered frame to the last (none with
    /// fewer than two).
    pub display_fps: Option<f64>,
    /// Median interval between a delivered frame and the frame composed before it, ms (none
    /// with fewer than two composed frames).
    pub interval_ms: Option<f64>,
    /// Median encoded bytes per delivered frame (all nodes).
    pub bytes_per_frame: f64,
    /// Median seed-layout bytes per delivered frame of what was sent.
    pub raw_bytes_per_frame: f64,
    /// Encoded bytes over 16 bytes per rendered fragment, summed over the delivered frames.
    pub bytes_vs_16n: f64,
    /// Fragments sent over fragments rendered, summed over the delivered frames.
    pub fragments_sent_share: f64,
    /// Same, without the first delivered frame (what the difference transfer saves in steady
    /// state).
    pub fragments_sent_share_after_first: f64,
    /// Reprojection: removals over fragments rendered, without the first delivered frame (the
    /// seed's difference lists counted each removal as a fragment).
    pub removals_share_after_first: f64,
    /// Medians per delivered node-frame, ms.
    pub render_ms: f64,
    /// Median.
    pub select_ms: f64,
    /// Median.
    pub encode_ms: f64,
    /// Median of the slowest node's transfer per delivered frame.
    pub transfer_ms: f64,
    /// Median.
    pub decode_ms: f64,
    /// Median over delivered frames.
    pub merge_ms: f64,
    /// Median over delivered frames.
    pub resolve_ms: f64,
}

impl Figures {
    /// The figures of `per_frame`'s delivered frames; `None` when no frame was delivered.
    fn of(per_frame: &[FrameStats]) -> Option<Figures> {
        let delivered: Vec<(usize, &FrameStats)> = per_frame
            .iter()
            .enumerate()
            .filter(|(_, f)| f.delivered())
            .collect();
        let (&(first, _), &(last, _)) = (delivered.first()?, delivered.last()?);
        let frames = || delivered.iter().map(|&(_, f)| f);
        let node_frames = || {
            frames()
                .flat_map(|f| f.nodes.iter())
                .filter(|n| n.status.delivered())
        };
        let sum = |f: &dyn Fn(&FrameStats) -> u64, skip: usize| -> u64 {
            frames().skip(skip).map(f).sum()
        };
        let ratio = |a: u64, b: u64| if b == 0 { 0.0 } else { a as f64 / b as f64 };
        // Seconds from the first delivered frame to the last: the intervals in between.
        let span_s: f64 = per_frame[first + 1..=last]
            .iter()
            .map(|f| f.interval_ms)
            .sum::<f64>()
            / 1e3;
        let intervals: Vec<f64> = delivered
            .iter()
            .filter(|&&(i, _)| i > 0)
            .map(|&(_, f)| f.interval_ms)
            .collect();
        Some(Figures {
            display_fps: (delivered.len() > 1 && span_s > 0.0)
                .then(|| (delivered.len() - 1) as f64 / span_s),
            interval_ms: (!intervals.is_empty()).then(|| median(intervals)),
            bytes_per_frame: median(frames().map(|f| f.bytes() as f64).collect()),
            raw_bytes_per_frame: median(frames().map(|f| f.raw_bytes() as f64).collect()),
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
                frames()
                    .map(|f| f.nodes.iter().map(|n| n.transfer_ms).fold(0.0, f64::max))
                    .collect(),
            ),
            decode_ms: median(node_frames().map(|n| n.decode_ms).collect()),
            merge_ms: median(frames().map(|f| f.merge_ms).collect()),
            resolve_ms: median(frames().map(|f| f.resolve_ms).collect()),
        })
    }
}

/// The nodes that missed frames, in `nodes` order.
fn shortfalls(nodes: &[String], per_frame: &[FrameStats]) -> Vec<NodeShortfall> {
    let mut out = Vec::new();
    for (i, node) in nodes.iter().enumerate() {
        let statuses = || {
            per_frame
                .iter()
                .filter_map(move |f| f.nodes.get(i).map(|n| (f.frame, n.status)))
        };
        let Some((first_missed, composed_as)) = statuses().find(|(_, s)| !s.delivered()) else {
            continue;
        };
        let delivered = statuses().filter(|(_, s)| s.delivered()).count();
        out.push(NodeShortfall {
            node: node.clone(),
            delivered,
            missed: per_frame.len() - delivered,
            first_missed,
            last_delivered: statuses()
                .filter(|(_, s)| s.delivered())
                .map(|(f, _)| f)
                .next_back(),
            composed_as,
        });
    }
    out
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
    /// Whether every node delivered every frame.
    pub outcome: Outcome,
    /// Frames composed.
    pub frames: usize,
    /// Frames at least one node delivered.
    pub delivered_frames: usize,
    /// The nodes that missed frames.
    pub shortfalls: Vec<NodeShortfall>,
    /// Rates, bytes and times of the delivered frames; absent when nothing was delivered.
    #[serde(flatten)]
    pub figures: Option<Figures>,
    /// Frames checked against the exact local render.
    pub checked_frames: usize,
    /// Frames with at least one bad pixel.
    pub frames_with_bad_pixels: usize,
    /// Most bad pixels in one frame.
    pub max_bad_pixels: u64,
    /// Bad-pixel threshold (max channel difference above it).
    pub bad_pixel_threshold: u8,
    /// Faults and reconnections.
    pub incidents: Vec<NodeIncident>,
    /// The frames were dropped on arrival, undecoded (`strata display --discard`): the rate is
    /// the nodes' alone, and the display's stages read 0.
    pub discarded: bool,
    /// Every frame.
    pub per_frame: Vec<FrameStats>,
}

impl FrameStats {
    /// Whether at least one node delivered this frame.
    pub fn delivered(&self) -> bool {
        self.nodes.iter().any(|n| n.status.delivered())
    }
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
        bad_pixel_threshold: u8,
        incidents: Vec<NodeIncident>,
        per_frame: Vec<FrameStats>,
    ) -> Self {
        let checked: Vec<u64> = per_frame.iter().filter_map(|f| f.bad_pixels).collect();
        let delivered_frames = per_frame.iter().filter(|f| f.delivered()).count();
        let shortfalls = shortfalls(&nodes, &per_frame);
        let outcome = if delivered_frames == 0 {
            Outcome::NothingDelivered
        } else if shortfalls.is_empty() {
            Outcome::Complete
        } else {
            Outcome::Degraded
        };
        Summary {
            scene,
            width,
            height,
            transfer,
            codec,
            outcome,
            frames: per_frame.len(),
            delivered_frames,
            shortfalls,
            figures: Figures::of(&per_frame),
            nodes,
            checked_frames: checked.len(),
            frames_with_bad_pixels: checked.iter().filter(|&&b| b > 0).count(),
            max_bad_pixels: checked.iter().copied().max().unwrap_or(0),
            bad_pixel_threshold,
            incidents,
            discarded: false,
            per_frame,
        }
    }

    /// The summary as pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// One line on how the run went, for a person.
    pub fn outcome_line(&self) -> String {
        match self.outcome {
            Outcome::Complete => "complete: every node delivered every frame".into(),
            Outcome::Degraded => format!(
                "DEGRADED: {} of {} node(s) missed frames; {} of {} frame(s) lack some node's \
                 current fragments",
                self.shortfalls.len(),
                self.nodes.len(),
                self.per_frame
                    .iter()
                    .filter(|f| f.nodes.iter().any(|n| !n.status.delivered()))
                    .count(),
                self.frames
            ),
            Outcome::NothingDelivered => format!(
                "FAILED: no node delivered any of the {} frame(s); nothing was displayed",
                self.frames
            ),
        }
    }

    /// A table for a person.
    pub fn to_table(&self) -> String {
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
        if self.discarded {
            let _ = writeln!(
                s,
                "  discarded         every frame on arrival, undecoded: the rate is the nodes' alone"
            );
        }
        let _ = writeln!(s, "  outcome           {}", self.outcome_line());
        for n in &self.shortfalls {
            let _ = writeln!(s, "  node {}: {}", n.node, shortfall_text(n, self.frames));
        }
        if let Some(f) = &self.figures {
            write_figures(
                &mut s,
                f,
                (self.delivered_frames, self.frames),
                self.discarded,
            );
        }
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

/// "delivered 2 of 5 frames; missed 3 from frame 2 (its last good frame, 1, was held)".
fn shortfall_text(n: &NodeShortfall, frames: usize) -> String {
    let instead = match (n.composed_as, n.last_delivered) {
        (NodeStatus::Held, Some(last)) => format!("its last good frame, {last}, was held"),
        (NodeStatus::Held, None) => "nothing of it was ever shown".to_string(),
        _ => "composed without it".to_string(),
    };
    format!(
        "delivered {} of {frames} frame(s); missed {} from frame {} ({instead})",
        n.delivered, n.missed, n.first_missed
    )
}

/// The rate, bytes and time lines of the table.
/// `discarded`: the rate is the nodes' (`--discard`), and the display's stages did not run.
fn write_figures(
    s: &mut String,
    f: &Figures,
    (delivered, frames): (usize, usize),
    discarded: bool,
) {
    use std::fmt::Write;
    let mb = |b: f64| b / 1e6;
    let of = if delivered < frames {
        format!(" (of the {delivered} delivered frame(s))")
    } else {
        String::new()
    };
    let rate = if discarded {
        "node rate   "
    } else {
        "display rate"
    };
    match (f.display_fps, f.interval_ms) {
        (Some(fps), Some(interval)) => {
            let _ = writeln!(
                s,
                "  {rate}      {fps:8.2} fps   (median interval {interval:.1} ms){of}"
            );
        }
        _ => {
            let _ = writeln!(
                s,
                "  {rate}           n/a   (fewer than two frames delivered)"
            );
        }
    }
    let _ = writeln!(
        s,
        "  bytes per frame   {:8.3} MB encoded, {:.3} MB in the list layout; {:.1}% of 16 B x fragments rendered{of}",
        mb(f.bytes_per_frame),
        mb(f.raw_bytes_per_frame),
        100.0 * f.bytes_vs_16n
    );
    let _ = writeln!(
        s,
        "  fragments sent    {:8.1}% of rendered ({:.1}% after the first frame)",
        100.0 * f.fragments_sent_share,
        100.0 * f.fragments_sent_share_after_first
    );
    if f.removals_share_after_first > 0.0 {
        let _ = writeln!(
            s,
            "  removals          {:8.1}% of rendered after the first frame (positions, not fragments)",
            100.0 * f.removals_share_after_first
        );
    }
    let _ = writeln!(
        s,
        "  node ms (median)  render {:.1}, select {:.1}, encode {:.1}",
        f.render_ms, f.select_ms, f.encode_ms
    );
    if discarded {
        let _ = writeln!(s, "  display ms        transfer {:.1}", f.transfer_ms);
    } else {
        let _ = writeln!(
            s,
            "  display ms        transfer {:.1}, decode {:.1}, merge {:.1}, resolve {:.1}",
            f.transfer_ms, f.decode_ms, f.merge_ms, f.resolve_ms
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame composed `interval_ms` after the previous one, with one entry per status: a
    /// node that delivered sent 1000 bytes of 10 fragments, the others nothing.
    fn frame(t: u64, interval_ms: f64, statuses: &[NodeStatus]) -> FrameStats {
        FrameStats {
            frame: t,
            nodes: statuses
                .iter()
                .enumerate()
                .map(|(i, &status)| {
                    let ok = status.delivered();
                    NodeFrame {
                        node: format!("node{i}:7400"),
                        status,
                        bytes: if ok { 1000 } else { 0 },
                        fragments_rendered: if ok { 10 } else { 0 },
                        fragments_sent: if ok { 10 } else { 0 },
                        ..NodeFrame::default()
                    }
                })
                .collect(),
            interval_ms,
            ..FrameStats::default()
        }
    }

    fn summary(per_frame: Vec<FrameStats>) -> Summary {
        let nodes = per_frame[0].nodes.iter().map(|n| n.node.clone()).collect();
        Summary::new(
            "mixed".into(),
            64,
            36,
            "full".into(),
            "lz4".into(),
            nodes,
            2,
            Vec::new(),
            per_frame,
        )
    }

    use NodeStatus::{Dropped, Held, Ok};

    #[test]
    fn a_run_where_every_node_delivered_is_complete() {
        let s = summary(vec![
            frame(0, 0.0, &[Ok, Ok]),
            frame(1, 100.0, &[Ok, Ok]),
            frame(2, 100.0, &[Ok, Ok]),
        ]);
        assert_eq!(s.outcome, Outcome::Complete);
        assert!(s.shortfalls.is_empty());
        let f = s.figures.as_ref().expect("figures");
        assert_eq!(f.display_fps, Some(10.0));
        assert_eq!(f.bytes_per_frame, 2000.0);
        assert!(
            s.to_table()
                .contains("complete: every node delivered every frame")
        );
    }

    #[test]
    fn a_run_where_no_node_delivered_has_no_rate_and_no_bytes() {
        let s = summary(vec![
            frame(0, 0.0, &[Dropped]),
            frame(1, 5.0, &[Dropped]),
            frame(2, 5.0, &[Dropped]),
        ]);
        assert_eq!(s.outcome, Outcome::NothingDelivered);
        assert_eq!(s.delivered_frames, 0);
        assert_eq!(s.figures, None);
        let table = s.to_table();
        assert!(table.contains("FAILED: no node delivered"), "{table}");
        for absent in ["display rate", "fps", "bytes per frame", "MB"] {
            assert!(!table.contains(absent), "{absent} in {table}");
        }
        let json: serde_json::Value = serde_json::from_str(&s.to_json()).unwrap();
        assert_eq!(json["outcome"], "nothing-delivered");
        assert!(json.get("display_fps").is_none(), "{json}");
        assert!(json.get("bytes_per_frame").is_none(), "{json}");
    }

    #[test]
    fn a_lost_node_makes_the_run_degraded_and_the_figures_count_delivered_frames_only() {
        // Node 1 dies after frame 1 and is held; then node 0 is lost too for frames 3-4.
        let s = summary(vec![
            frame(0, 0.0, &[Ok, Ok]),
            frame(1, 100.0, &[Ok, Ok]),
            frame(2, 100.0, &[Ok, Held]),
            frame(3, 7.0, &[Held, Held]),
            frame(4, 7.0, &[Held, Held]),
        ]);
        assert_eq!(s.outcome, Outcome::Degraded);
        assert_eq!(s.delivered_frames, 3);
        assert_eq!(
            s.shortfalls[1],
            NodeShortfall {
                node: "node1:7400".into(),
                delivered: 2,
                missed: 3,
                first_missed: 2,
                last_delivered: Some(1),
                composed_as: Held,
            }
        );
        assert_eq!(s.shortfalls[0].first_missed, 3);
        let f = s.figures.as_ref().expect("figures");
        // Frames 0-2 over 200 ms; the quick empty frames 3-4 do not count.
        assert_eq!(f.display_fps, Some(10.0));
        assert_eq!(f.bytes_per_frame, 2000.0);
        let table = s.to_table();
        assert!(
            table.contains("DEGRADED: 2 of 2 node(s) missed frames"),
            "{table}"
        );
        assert!(
            table.contains(
                "node node1:7400: delivered 2 of 5 frame(s); missed 3 from frame 2 \
                 (its last good frame, 1, was held)"
            ),
            "{table}"
        );
        let json: serde_json::Value = serde_json::from_str(&s.to_json()).unwrap();
        assert_eq!(json["outcome"], "degraded");
        assert_eq!(json["per_frame"][2]["nodes"][1]["status"], "held");
    }
}
