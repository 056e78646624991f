//! The difference protocol without sockets: random frame sequences of several nodes, deltas,
//! stale masks and fixups applied exactly as the display does — the merged image must equal the
//! resolve of the union of the nodes' current frames at every step.

use std::sync::Arc;

use proptest::prelude::*;
use strata_core::{DeepFrame, Fragment, ObjectId, Rgba8};
use strata_remote::difference::{DiffEncoder, NodeCopy, stale_shared};
use strata_remote::merge::merge_resolve;
use strata_remote::select::restrict;

const W: u32 = 5;
const H: u32 = 3;
const BG: [f32; 3] = [0.9, 0.8, 0.7];

/// A frame of node `node`: few depths and colours so that runs collide, move and keep colours.
fn frame_strategy(node: u32) -> impl Strategy<Value = DeepFrame> {
    let frag = (0u8..6, 0u8..3, 1u8..=255).prop_map(move |(d, c, a)| Fragment {
        depth: f32::from(d) / 8.0,
        color: Rgba8([c * 100, 50, 200 - c * 60, a]),
        object: ObjectId(node),
    });
    proptest::collection::vec(proptest::collection::vec(frag, 0..4), (W * H) as usize)
        .prop_map(|lists| DeepFrame::from_pixel_lists(W, H, &lists).unwrap())
}

/// What a node does in a step: render the same frame, a new one, or move its surfaces in depth
/// without changing their colours (the case that makes held copies stale).
#[derive(Clone, Copy, Debug)]
enum Step {
    Keep,
    New,
    Shift(u8),
}

fn step() -> impl Strategy<Value = Step> {
    prop_oneof![
        Just(Step::Keep),
        Just(Step::New),
        (1u8..8).prop_map(Step::Shift)
    ]
}

/// Sequences of steps for two nodes.
fn sequence() -> impl Strategy<Value = Vec<(DeepFrame, DeepFrame, Step, Step)>> {
    proptest::collection::vec(
        (frame_strategy(1), frame_strategy(2), step(), step()),
        1..10,
    )
}

/// `f` with every depth moved to `d / 2 + k / 16`: same colours, same order within each run.
fn shifted(f: &DeepFrame, k: u8) -> DeepFrame {
    let lists: Vec<Vec<Fragment>> = (0..(W * H) as usize)
        .map(|p| {
            f.run(p)
                .iter()
                .map(|mut x| {
                    x.depth = x.depth / 2.0 + f32::from(k) / 16.0;
                    x
                })
                .collect()
        })
        .collect();
    DeepFrame::from_pixel_lists(W, H, &lists).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn deltas_and_fixups_reproduce_the_exact_merge(steps in sequence()) {
        let mut enc = [DiffEncoder::new(BG, 0), DiffEncoder::new(BG, 0)];
        let mut copies = [NodeCopy::empty(W, H), NodeCopy::empty(W, H)];
        let mut current: [Option<Arc<DeepFrame>>; 2] = [None, None];
        for (a, b, step_a, step_b) in steps {
            for (i, (f, step)) in [(a, step_a), (b, step_b)].into_iter().enumerate() {
                current[i] = Some(Arc::new(match (&current[i], step) {
                    (Some(c), Step::Keep) => (**c).clone(),
                    (Some(c), Step::Shift(k)) => shifted(c, k),
                    _ => f,
                }));
            }
            let frames: Vec<Arc<DeepFrame>> = current.iter().map(|f| f.clone().unwrap()).collect();
            for i in 0..2 {
                let d = enc[i].diff(frames[i].clone());
                copies[i].apply_delta(&d.changed, &d.stale, &d.runs);
            }
            let asked = stale_shared(&[&copies[0], &copies[1]], &[true, true]);
            for i in 0..2 {
                if !asked[i].is_empty() {
                    let runs = restrict(&frames[i], &asked[i]);
                    copies[i].apply(&asked[i], &runs);
                }
            }
            let shown = merge_resolve(&[copies[0].frame(), copies[1].frame()], W, H, BG);
            let exact = merge_resolve(&[&frames[0], &frames[1]], W, H, BG);
            prop_assert_eq!(shown, exact);
        }
    }

    #[test]
    fn an_unchanged_frame_sends_and_marks_nothing(f in frame_strategy(1)) {
        let f = Arc::new(f);
        let mut enc = DiffEncoder::new(BG, 0);
        let first = enc.diff(f.clone());
        prop_assert_eq!(first.runs.fragment_count(), f.fragment_count());
        let again = enc.diff(f);
        prop_assert!(again.changed.is_empty());
        prop_assert!(again.stale.is_empty());
    }
}
