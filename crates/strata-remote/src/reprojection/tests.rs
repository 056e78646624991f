//! Node and display side by side, without sockets.

use super::*;
use strata_core::{DeepFrame, Fragment, ObjectId, PackedNormal, Rgb8Image, Rgba8, Shading};
use strata_raster::{FragmentOutput, FrameInput, Rasterizer};
use strata_scene::Scene;
use strata_scene::{Animation, SearchPath, open_scene};
use strata_stores::{MethodOptions, create};
use strata_wire::{PixelMask, Removals};

const W: u32 = 128;
const H: u32 = 96;

/// `scene` turning `deg` degrees per frame about y.
fn scene(name: &str, deg: f32) -> Scene {
    let mut s = open_scene(name, &SearchPath::new([])).expect("built-in scene");
    s.animation = Some(Animation {
        frames: 72,
        rotate_deg_per_frame: glam::Vec3::new(0.0, deg, 0.0),
    });
    s
}

/// Renders `objects` of `scene` at `frame` as normal or shaded fragments, `W` × `H`.
fn render(scene: &Scene, objects: &[ObjectId], frame: u64, output: FragmentOutput) -> DeepFrame {
    let mut input = FrameInput::from_scene(scene, frame as u32);
    input.objects.retain(|o| objects.contains(&o.id));
    input.output = output;
    input.width = W;
    input.height = H;
    input.projection = scene.camera.projection(W, H);
    let mut store = create("abuffer", &MethodOptions::default()).expect("the A-buffer");
    store.clear(W, H).expect("clear");
    store
        .capture(&mut Rasterizer::default(), &input, &mut Default::default())
        .expect("capture");
    store.deep_frame().expect("exports").expect("a DeepFrame")
}

fn view(scene: &Scene, objects: &[ObjectId], frame: u64) -> View {
    View::new(
        scene,
        objects,
        crate::animation_frame(frame).expect("a small frame number"),
        (W, H),
        scene.camera.view(),
        scene.camera.projection(W, H),
    )
}

fn max_channel_diff(a: &Rgb8Image, b: &Rgb8Image) -> u8 {
    a.as_bytes()
        .iter()
        .zip(b.as_bytes())
        .map(|(x, y)| x.abs_diff(*y))
        .max()
        .unwrap_or(0)
}

/// Runs node and display side by side for `frames` frames; returns the fragments inserted per
/// frame and checks every displayed image against the exact render.
fn run(scene: &Scene, frames: u64, tolerance: u8) -> Vec<usize> {
    let ids: Vec<ObjectId> = scene.objects.iter().map(|o| o.id).collect();
    let mut enc = ReprojEncoder::new(tolerance);
    let mut copy = ReprojCopy::empty(W, H);
    let mut sent = Vec::new();
    for t in 0..frames {
        let v = view(scene, &ids, t);
        let rendered = render(scene, &ids, t, FragmentOutput::PackedNormal);
        let d = enc.encode(&v, &rendered).expect("encodes");
        copy.apply(&v, &d.touched, &d.removals, &d.inserts)
            .expect("the display follows the node");
        assert_eq!(copy.held().len() as u64, d.held);
        // The digest both ends computed band by band is that of the whole list.
        assert_eq!(copy.held().digest(), d.removals.checksum());
        assert_eq!(copy.held().len(), rendered.fragment_count());
        let image = copy.held().to_frame().resolve(scene.background);
        let exact = render(scene, &ids, t, FragmentOutput::Shaded).resolve(scene.background);
        let diff = max_channel_diff(&image, &exact);
        assert!(
            diff <= tolerance + 1,
            "frame {t}: a channel differs by {diff} (tolerance {tolerance})"
        );
        sent.push(d.inserts.fragment_count());
    }
    sent
}

#[test]
fn static_view_sends_nothing_after_the_first_frame() {
    let sent = run(&scene("spheres", 0.0), 4, 1);
    assert!(sent[0] > 1000, "{sent:?}");
    assert!(sent[1..].iter().all(|&n| n == 0), "{sent:?}");
}

#[test]
fn turning_scene_stays_within_the_tolerance_and_sends_less_than_everything() {
    let sent = run(&scene("spheres", 2.0), 6, 2);
    assert!(sent[1..].iter().all(|&n| n < sent[0]), "{sent:?}");
}

#[test]
fn zero_tolerance_is_exact_colour_for_colour() {
    run(&scene("mixed", 5.0), 4, 0);
}

#[test]
fn a_removal_beyond_a_run_or_a_wrong_digest_is_an_error_and_keeps_the_copy() {
    let s = scene("spheres", 0.0);
    let ids: Vec<ObjectId> = s.objects.iter().map(|o| o.id).collect();
    let v = view(&s, &ids, 0);
    let mut enc = ReprojEncoder::new(1);
    let d = enc
        .encode(&v, &render(&s, &ids, 0, FragmentOutput::PackedNormal))
        .expect("encodes");
    let mut copy = ReprojCopy::empty(W, H);
    let mut bad = d.removals.clone();
    bad.set_checksum(d.removals.checksum() ^ 1);
    assert!(matches!(
        copy.apply(&v, &d.touched, &bad, &d.inserts),
        Err(ApplyError::Diverged { .. })
    ));
    assert!(copy.held().is_empty());
    copy.apply(&v, &d.touched, &d.removals, &d.inserts).unwrap();
    // A removal at a position the pixel does not hold.
    let p = d.touched.iter().next().unwrap();
    let touched = PixelMask::from_fn(W * H, |q| q == p);
    let mut r = Removals::new(0);
    r.push_pixel([1000]);
    let before = copy.held().clone();
    assert!(matches!(
        copy.apply(&v, &touched, &r, &DeepFrame::empty(W, 1)),
        Err(ApplyError::Mismatch(_))
    ));
    assert_eq!(copy.held(), &before);
    // An insert past the touched pixels' runs, in the padding of the compacted inserts (the
    // display would ignore it, so a node that sends one is broken).
    let f = render(&s, &ids, 0, FragmentOutput::PackedNormal)
        .run(p as usize)
        .iter()
        .next()
        .expect("a touched pixel of the first frame was rendered");
    let stray = DeepFrame::build(W, 1, &vec_with_one(W as usize, 1), |_, out| out.push(f)).unwrap();
    let mut r = Removals::new(0);
    r.push_pixel([]);
    assert!(matches!(
        copy.apply(&v, &touched, &r, &stray),
        Err(ApplyError::Mismatch(m)) if m.contains("1 inserted fragments lie past the touched")
    ));
    assert_eq!(copy.held(), &before);
    // The same insert at the touched pixel, but laid out over the whole view (version 5 of
    // the wire format), not compacted.
    let whole = DeepFrame::build(
        W,
        H,
        &vec_with_one((W * H) as usize, p as usize),
        |_, out| out.push(f),
    )
    .unwrap();
    assert!(matches!(
        copy.apply(&v, &touched, &r, &whole),
        Err(ApplyError::Mismatch(m)) if m.contains("compacted inserts")
    ));
    assert_eq!(copy.held(), &before);
    // A band told to lose more fragments than it holds in all (its next length would be
    // negative): the error names the pixel whose run is too short.
    let band_rows = 16;
    let q = W / 2;
    let band_total: usize = (0..band_rows * W)
        .map(|x| before.run(x as usize).len())
        .sum();
    let held_at_q = before.run(q as usize).len();
    let touched = PixelMask::from_fn(W * H, |x| x == q);
    let mut r = Removals::new(0);
    r.push_pixel(0..=band_total as u32);
    assert!(matches!(
        copy.apply(&v, &touched, &r, &DeepFrame::empty(W, 1)),
        Err(ApplyError::Mismatch(m)) if m.contains(&format!("pixel {q} holds {held_at_q} fragments"))
    ));
    assert_eq!(copy.held(), &before);
}

/// Per-pixel counts of a frame with one fragment at pixel `p`.
/// Run lengths of `pixels` pixels: one fragment at pixel `p`, none elsewhere.
fn vec_with_one(pixels: usize, p: usize) -> Vec<u32> {
    let mut counts = vec![0; pixels];
    counts[p] = 1;
    counts
}

#[test]
fn recycled_deltas_give_the_deltas_of_fresh_ones() {
    // Turning fast, so the inserts grow and shrink from frame to frame.
    let s = scene("mixed", 25.0);
    let ids: Vec<ObjectId> = s.objects.iter().map(|o| o.id).collect();
    let deltas = |recycle: bool| {
        let mut enc = ReprojEncoder::new(1);
        let mut out = Vec::new();
        for t in 0..5 {
            let rendered = render(&s, &ids, t, FragmentOutput::PackedNormal);
            let d = enc.encode(&view(&s, &ids, t), &rendered).expect("encodes");
            out.push((
                d.touched.clone(),
                d.removals.clone(),
                d.inserts.clone(),
                d.held,
            ));
            if recycle {
                enc.recycle(d);
            }
        }
        out
    };
    let (fresh, recycled) = (deltas(false), deltas(true));
    // After the first frame (which sends everything) the inserts shrink and grow again, so
    // recycled frames are both larger and smaller than the next.
    let sizes: Vec<usize> = fresh.iter().map(|d| d.2.fragment_count()).collect();
    assert!(sizes[1..].windows(2).any(|w| w[1] < w[0]), "{sizes:?}");
    assert!(sizes[1..].windows(2).any(|w| w[1] > w[0]), "{sizes:?}");
    assert!(fresh == recycled, "a recycled frame changed a delta");
}

#[test]
fn digest_and_reprojection_do_not_depend_on_the_thread_count() {
    let s = scene("mixed", 5.0);
    let ids: Vec<ObjectId> = s.objects.iter().map(|o| o.id).collect();
    let go = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let mut enc = ReprojEncoder::new(1);
                let mut digests = Vec::new();
                for t in 0..3 {
                    let d = enc
                        .encode(
                            &view(&s, &ids, t),
                            &render(&s, &ids, t, FragmentOutput::PackedNormal),
                        )
                        .expect("encodes");
                    digests.push((d.removals.checksum(), d.inserts.fragment_count()));
                }
                digests
            })
    };
    assert_eq!(go(1), go(3));
}

#[test]
fn an_entry_is_36_bytes_as_the_layout_says() {
    // held.rs's layout and the README's memory figures count on it.
    assert_eq!(std::mem::size_of::<Entry>(), 36);
}

#[test]
fn merge_pixel_keeps_projected_first_on_ties() {
    let e = |d: f32, o: u32| Entry {
        fragment: Fragment {
            depth: d,
            color: Rgba8([1, 2, 3, 4]),
            object: ObjectId(o),
        },
        surfel: Surfel::default(),
    };
    let mut tie = e(0.5, 1);
    tie.surfel.position[0] = 9.0;
    let mut out = Vec::new();
    merge_pixel(
        &[e(0.1, 0), e(0.5, 1), e(0.9, 2)],
        &[0],
        &[tie, e(0.95, 3)],
        &mut out,
    );
    assert_eq!(out, [e(0.5, 1), tie, e(0.9, 2), e(0.95, 3)]);
}

#[test]
fn long_runs_sort_stably_like_short_ones() {
    // Keys with many ties, in runs on both sides of the insertion-sort cut-off.
    for n in [5usize, 32, 33, 200] {
        let run: Vec<(u32, usize)> = (0..n).map(|i| ((i * 7 % 5) as u32, i)).collect();
        let mut sorted = run.clone();
        sort_stably_by_key(&mut sorted, |&(k, _)| k);
        let mut want = run.clone();
        want.sort_by_key(|&(k, _)| k); // the standard library's sort is stable
        assert_eq!(sorted, want, "{n}");
    }
}

#[test]
fn a_pixel_losing_more_than_a_removal_list_can_name_is_an_error_not_a_panic() {
    let s = scene("spheres", 0.0);
    let ids: Vec<ObjectId> = s.objects.iter().map(|o| o.id).collect();
    let v = View::new(
        &s,
        &ids,
        0,
        (1, 1),
        s.camera.view(),
        s.camera.projection(1, 1),
    );
    let deep: Vec<Fragment> = (0..70_000u32)
        .map(|i| Fragment {
            depth: 0.5 + i as f32 * 1e-6,
            color: Rgba8::from_bits(PackedNormal::pack([0.0, 0.0, 1.0]).to_bits()),
            object: ids[0],
        })
        .collect();
    let mut enc = ReprojEncoder::new(0);
    let first = DeepFrame::from_pixel_lists(1, 1, &[deep]).unwrap();
    assert_eq!(
        enc.encode(&v, &first).unwrap().inserts.fragment_count(),
        70_000
    );
    let e = enc.encode(&v, &DeepFrame::empty(1, 1)).unwrap_err();
    assert_eq!(e.removals, 70_000);
    // The encoder starts over: the next frame is sent whole.
    assert_eq!(
        enc.encode(&v, &first).unwrap().inserts.fragment_count(),
        70_000
    );
}

#[test]
fn ambiguous_pixels_are_where_two_nodes_come_closer_than_the_error_bound() {
    let f = |depth: f32, o: u32| Fragment {
        depth,
        color: Rgba8([9, 9, 9, 128]),
        object: ObjectId(o),
    };
    // Pixel 0: the nodes 1e-4 apart; 1: one node only; 2: 0.1 apart; 3: a node's own two
    // fragments close together; 4: empty.
    let a = DeepFrame::from_pixel_lists(
        5,
        1,
        &[
            vec![f(0.5, 0)],
            vec![f(0.5, 0)],
            vec![f(0.2, 0)],
            vec![f(0.3, 0), f(0.30001, 0)],
            vec![],
        ],
    )
    .unwrap();
    let b = DeepFrame::from_pixel_lists(
        5,
        1,
        &[vec![f(0.5001, 1)], vec![], vec![f(0.3, 1)], vec![], vec![]],
    )
    .unwrap();
    let masks = ambiguous(&[&a, &b], &[1e-3, 0.0], &[true, true]);
    let pixels = |m: &PixelMask| m.iter().collect::<Vec<u32>>();
    assert_eq!(pixels(&masks[0]), [0]);
    assert_eq!(pixels(&masks[1]), [0]);
    // Exact depths on both sides: nothing to fix up.
    let masks = ambiguous(&[&a, &b], &[0.0, 0.0], &[true, true]);
    assert!(masks.iter().all(PixelMask::is_empty));
    // A node not taking part this frame is asked for nothing.
    let masks = ambiguous(&[&a, &b], &[1e-3, 0.0], &[true, false]);
    assert_eq!((pixels(&masks[0]), pixels(&masks[1])), (vec![0], vec![]));
}

/// A deterministic stream of awkward values: ordinary ones of many scales and, now and then,
/// signed zeros, infinities, NaN, huge and tiny numbers, and arbitrary bit patterns.
struct Awkward(u64);

impl Awkward {
    fn bits(&mut self) -> u32 {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 32) as u32
    }
    fn unit(&mut self) -> f32 {
        self.bits() as f32 / u32::MAX as f32
    }
    fn f32(&mut self, scale: f32) -> f32 {
        let r = self.bits();
        match r % 16 {
            0 => [
                0.0,
                -0.0,
                f32::INFINITY,
                f32::NEG_INFINITY,
                f32::NAN,
                1e-30,
                1e30,
                -1e30,
            ][(r >> 4) as usize % 8],
            1 => f32::from_bits(self.bits()),
            _ => (self.unit() - 0.5) * 2.0 * scale,
        }
    }
}

/// `mixed` with its first object unlit, so that batches of both kinds of shading are checked.
fn lit_and_unlit() -> (Scene, Vec<ObjectId>) {
    let mut s = scene("mixed", 5.0);
    s.objects[0].material.shading = Shading::Unlit;
    let ids = s.objects.iter().map(|o| o.id).collect();
    (s, ids)
}

/// The views the lane tests use: the scene's camera at frames 0, 3 and 40, and a camera
/// looking at the scene askew, so that every matrix entry is non-zero and the order of the
/// additions shows in the bits.
fn lane_test_views(s: &Scene, ids: &[ObjectId]) -> Vec<View> {
    let askew = glam::Mat4::look_at_rh(
        glam::Vec3::new(0.9, 0.6, 2.3),
        glam::Vec3::new(0.1, -0.05, 0.0),
        glam::Vec3::new(0.1, 1.0, 0.05),
    );
    let mut views: Vec<View> = [0, 3, 40].iter().map(|&t| view(s, ids, t)).collect();
    views.push(View::new(
        s,
        ids,
        7,
        (W, H),
        askew,
        s.camera.projection(W, H),
    ));
    views
}

/// `x`'s bits, every NaN as one: IEEE arithmetic fixes values, not NaN payloads.
fn bits(x: f32) -> u32 {
    if x.is_nan() {
        f32::NAN.to_bits()
    } else {
        x.to_bits()
    }
}

/// The bits of a moved fragment, so that -0 and 0 differ and NaN equals itself.
fn moved_bits(m: Option<(u32, Fragment)>) -> (u32, u32, Rgba8, ObjectId) {
    match m {
        Some((p, f)) => (p, bits(f.depth), f.color, f.object),
        None => (u32::MAX, 0, Rgba8::default(), ObjectId::default()),
    }
}

fn entry_bits(e: &Entry) -> ([u32; 7], Rgba8, ObjectId) {
    let (p, n) = (e.surfel.position, e.surfel.normal);
    (
        [p[0], p[1], p[2], n[0], n[1], n[2], e.fragment.depth].map(bits),
        e.fragment.color,
        e.fragment.object,
    )
}

#[test]
fn surfels_moved_in_lanes_are_those_moved_one_at_a_time_bit_for_bit() {
    let (s, ids) = lit_and_unlit();
    let mut values = Awkward(0x5EED);
    let unknown = ObjectId(ids.iter().map(|o| o.0).max().unwrap() + 7);
    let mut checked = [0usize; 2];
    for v in lane_test_views(&s, &ids) {
        for &object in ids.iter().chain([&unknown]) {
            for round in 0..400 {
                // Mostly points near the scene (in view), sometimes anywhere.
                let scale = [0.6, 2.0, 50.0, 1e6][round % 4];
                let surfels: [Surfel; lanes::LANES] = std::array::from_fn(|_| Surfel {
                    position: std::array::from_fn(|_| values.f32(scale)),
                    normal: std::array::from_fn(|_| values.f32(1.0)),
                });
                let mut out = [(0, Fragment::default()); lanes::LANES];
                v.project_batch(object, &surfels, &mut out);
                for (surfel, lane) in surfels.iter().zip(out) {
                    let one = v.project(object, surfel);
                    checked[usize::from(one.is_some())] += 1;
                    let lane = (lane.0 != u32::MAX).then_some(lane);
                    assert_eq!(
                        moved_bits(lane),
                        moved_bits(one),
                        "{surfel:?} of {object:?}"
                    );
                }
            }
        }
    }
    // Both outcomes were exercised in numbers.
    assert!(checked.iter().all(|&n| n > 10_000), "{checked:?}");
}

#[test]
fn entries_made_in_lanes_are_those_made_one_at_a_time_bit_for_bit() {
    let (s, ids) = lit_and_unlit();
    let mut values = Awkward(0xD1CE);
    // Unknown objects besides the scene's, more objects than `lanes::Pending` keeps batches
    // open for, so that batches of known objects are also flushed early to make room.
    let max = ids.iter().map(|o| o.0).max().unwrap();
    let objects: Vec<ObjectId> = (ids.iter().copied())
        .chain((7..13).map(|k| ObjectId(max + k)))
        .collect();
    assert!(objects.len() > 8);
    let counts: Vec<u32> = (0..W * H).map(|_| values.bits() % 5).collect();
    // Runs of random length, depths and normal bits (the "no normal" pattern included);
    // sorted, as a DeepFrame's runs are. Objects: in every third row each fragment's at
    // random (batches gathered object by object); in the others mostly one object, known or
    // not (whole batches straight from the frame's columns), now and then another.
    let (known_object, unknown_object) = (ids[0], objects[objects.len() - 1]);
    let runs: Vec<Vec<Fragment>> = counts
        .iter()
        .enumerate()
        .map(|(p, &n)| {
            let mut run: Vec<Fragment> = (0..n)
                .map(|_| Fragment {
                    depth: values.unit(),
                    color: Rgba8::from_bits(if values.bits().is_multiple_of(8) {
                        PackedNormal::NONE.to_bits()
                    } else {
                        values.bits()
                    }),
                    object: match (p / W as usize) % 3 {
                        1 if !values.bits().is_multiple_of(16) => known_object,
                        2 if !values.bits().is_multiple_of(16) => unknown_object,
                        _ => objects[values.bits() as usize % objects.len()],
                    },
                })
                .collect();
            run.sort_by_key(Fragment::order_key);
            run
        })
        .collect();
    let frame = DeepFrame::build(W, H, &counts, |p, out| out.extend_from_slice(&runs[p]))
        .expect("a valid frame");
    let (mut entries, mut known) = (Vec::new(), Vec::new());
    let mut checked = [0usize; 2];
    for v in lane_test_views(&s, &ids) {
        for row in 0..H as usize {
            v.row_entries(
                &super::lanes::FrameRows::of(&frame),
                row,
                &mut entries,
                &mut known,
            );
            let first = frame.offsets()[row * W as usize] as usize;
            assert_eq!(
                entries.len(),
                frame.offsets()[(row + 1) * W as usize] as usize - first
            );
            for p in row * W as usize..(row + 1) * W as usize {
                for (k, f) in (frame.offsets()[p] as usize..).zip(frame.run(p).iter()) {
                    let one = v.entry(p as u32, f);
                    assert_eq!(known[k - first], one.is_some(), "{f:?} at {p}");
                    checked[usize::from(one.is_some())] += 1;
                    if let Some(one) = one {
                        assert_eq!(
                            entry_bits(&entries[k - first]),
                            entry_bits(&one),
                            "{f:?} at {p}"
                        );
                    }
                }
            }
        }
    }
    assert!(checked.iter().all(|&n| n > 1_000), "{checked:?}");
}

#[test]
fn reprojection_is_the_stable_sort_of_every_moved_entry_at_any_thread_count_and_size() {
    let (s, ids) = lit_and_unlit();
    // Something held: a few frames of the node and display side by side.
    let mut enc = ReprojEncoder::new(1);
    let mut copy = ReprojCopy::empty(W, H);
    for t in 0..3 {
        let v = view(&s, &ids, t);
        let d = enc
            .encode(&v, &render(&s, &ids, t, FragmentOutput::PackedNormal))
            .expect("encodes");
        copy.apply(&v, &d.touched, &d.removals, &d.inserts)
            .expect("applies");
    }
    let held = copy.held();
    assert!(held.len() > 10_000, "{}", held.len());
    // The definition: every entry moved in list order (kept as it is where its object is
    // placed and seen as in the list's view, that of frame 2), appended to its new pixel, each
    // run then sorted stably.
    let held_view = view(&s, &ids, 2);
    let reference = |v: &View| {
        let (w, h) = v.size();
        let mut runs = vec![Vec::new(); w as usize * h as usize];
        for p in 0..(W * H) as usize {
            for e in held.run(p) {
                let object = e.fragment.object;
                let moved = if v.unchanged(&held_view, object.0 as usize) {
                    Some((p as u32, e.fragment))
                } else {
                    v.project(object, &e.surfel)
                };
                if let Some((q, f)) = moved {
                    runs[q as usize].push(Entry {
                        fragment: f,
                        surfel: e.surfel,
                    });
                }
            }
        }
        runs.iter_mut().for_each(|r| sort_entries(r));
        runs
    };
    // Views of the next frames at this size, and smaller and larger ones.
    let sized = |t: u64, (w, h): (u32, u32)| {
        View::new(
            &s,
            &ids,
            t as u32,
            (w, h),
            s.camera.view(),
            s.camera.projection(w, h),
        )
    };
    // Frame 2 is where the list was made: every object unchanged, kept bit for bit. Then,
    // at frame 2, the first object left out (unknown) beside unchanged ones, and one object
    // moved beside unchanged ones: entries of one moving object taken as they lie next to
    // entries kept one at a time.
    let camera = (s.camera.view(), s.camera.projection(W, H));
    let mut nudged = s.clone();
    nudged.objects[1].translate.x += 0.02;
    let views = [
        sized(4, (W, H)),
        sized(2, (W, H)),
        View::new(&s, &ids[1..], 2, (W, H), camera.0, camera.1),
        View::new(&nudged, &ids, 2, (W, H), camera.0, camera.1),
        sized(9, (W / 2 + 3, H / 2 + 5)),
        sized(6, (W * 2, H + 17)),
        sized(5, (1, 1)),
        // No pixel at all: everything leaves the view.
        sized(7, (0, H)),
        sized(8, (W, 0)),
    ];
    let mut out = Held::empty(0, 0);
    let mut scratch = Scratch::default();
    let mut reuse = DeepFrame::empty(0, 0);
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        // The buffers are reused from view to view, larger and smaller, stale data in them.
        for v in views.iter().chain(views.iter().rev()) {
            pool.install(|| held.reproject_into(v, &mut out, &mut scratch));
            let want = reference(v);
            let (w, h) = v.size();
            assert_eq!(out.len(), want.iter().map(Vec::len).sum::<usize>());
            for (p, r) in want.iter().enumerate() {
                let got: Vec<_> = out.run(p).iter().map(entry_bits).collect();
                let want: Vec<_> = r.iter().map(entry_bits).collect();
                assert_eq!(got, want, "pixel {p} of {w}x{h}, {threads} threads");
            }
            // The ends sort band by band from `move_to` in their own band tasks (pooled
            // buffers, offsets from zero): every band's runs are the list's.
            let mut band_scratch = Scratch::default();
            let moved = held.move_to(v, &mut band_scratch);
            assert_eq!(moved.band_count(), (h as usize).div_ceil(BAND_ROWS));
            let bands: Vec<usize> = (0..moved.band_count()).collect();
            pool.install(|| {
                rayon::iter::ParallelIterator::for_each(
                    rayon::iter::IntoParallelRefIterator::par_iter(&bands),
                    |&d| {
                        moved.sort_band(d, |band| {
                            for p in moved.band_pixels(d) {
                                let got: Vec<_> = band.run(p).iter().map(entry_bits).collect();
                                let want: Vec<_> = out.run(p).iter().map(entry_bits).collect();
                                assert_eq!(got, want, "band {d}, pixel {p} of {w}x{h}");
                            }
                            let (all, offs) = band.span(moved.band_pixels(d));
                            assert_eq!((all.len(), offs[0]), (moved.band_len(d), 0));
                        })
                    },
                )
            });
            // The display's frame of it, in the last view's buffers, has the same runs.
            let reused = std::mem::replace(&mut reuse, DeepFrame::empty(0, 0));
            let frame = pool.install(|| out.frame_into(reused));
            assert_eq!((frame.width(), frame.height()), (w, h));
            assert_eq!(frame.fragment_count(), out.len());
            for p in 0..(w * h) as usize {
                let got: Vec<_> = frame.run(p).iter().collect();
                let want: Vec<_> = out.run(p).iter().map(|e| e.fragment).collect();
                assert_eq!(got, want, "frame pixel {p} of {w}x{h}, {threads} threads");
            }
            reuse = frame;
        }
    }
}

#[test]
fn the_band_digest_changes_with_any_run_length_fragment_position_or_order() {
    let entry = |i: u32| Entry {
        fragment: Fragment {
            depth: 0.1 * i as f32,
            color: Rgba8([i as u8, 2, 3, 128]),
            object: ObjectId(i % 3),
        },
        surfel: Surfel {
            position: [i as f32, 0.5, -1.0],
            normal: [0.0, 0.0, 1.0],
        },
    };
    let entries: Vec<Entry> = (0..9).map(entry).collect();
    let counts = [2, 0, 3, 1, 0, 3];
    let digest = super::held::band_digest;
    let base = digest(4, &entries, &counts);
    assert_eq!(base, digest(4, &entries, &counts), "deterministic");
    assert_ne!(base, digest(5, &entries, &counts), "the band number");
    // The same entries split differently between pixels.
    assert_ne!(base, digest(4, &entries, &[3, 0, 2, 1, 0, 3]));
    assert_ne!(base, digest(4, &entries, &[2, 0, 3, 1, 3, 0]));
    // Two entries swapped.
    let mut swapped = entries.clone();
    swapped.swap(3, 4);
    assert_ne!(base, digest(4, &swapped, &counts));
    // One word of one entry changed: depth, colour, object, each position coordinate.
    let edits: [fn(&mut Entry); 6] = [
        |e| e.fragment.depth = f32::from_bits(e.fragment.depth.to_bits() ^ 1),
        |e| e.fragment.color.0[1] ^= 1,
        |e| e.fragment.object.0 ^= 1,
        |e| e.surfel.position[0] = f32::from_bits(e.surfel.position[0].to_bits() ^ 1),
        |e| e.surfel.position[1] = f32::from_bits(e.surfel.position[1].to_bits() ^ 1),
        |e| e.surfel.position[2] = f32::from_bits(e.surfel.position[2].to_bits() ^ 1),
    ];
    for (k, edit) in edits.iter().enumerate() {
        for i in [0, 4, 8] {
            let mut changed = entries.clone();
            edit(&mut changed[i]);
            assert_ne!(base, digest(4, &changed, &counts), "edit {k} of entry {i}");
        }
    }
    // Every NaN is one value.
    let mut a = entries.clone();
    let mut b = entries.clone();
    a[2].surfel.position[1] = f32::NAN;
    b[2].surfel.position[1] = f32::from_bits(0x7fc0_1234);
    assert_eq!(digest(4, &a, &counts), digest(4, &b, &counts));
}

/// Records every batch [`lanes::Pending`] hands over.
#[derive(Default)]
struct Batches(Vec<(ObjectId, Vec<(u32, u32)>)>);

impl lanes::Flush<u32, u32> for Batches {
    fn flush(
        &mut self,
        object: ObjectId,
        to: &[u32; lanes::LANES],
        input: &[u32; lanes::LANES],
        len: usize,
    ) {
        let items = to.iter().zip(input).take(len).map(|(&t, &i)| (t, i));
        self.0.push((object, items.collect()));
    }
}

#[test]
fn pending_batches_hand_over_every_item_once_with_its_own_object() {
    // Few objects (every batch stays open), as many as fit, and more than fit (batches are
    // flushed early to make room), in runs of one object and interleaved item by item.
    for objects in [1u32, 3, 8, 9, 40] {
        for run in [1usize, 3, 50] {
            let mut values = Awkward(0x5EED ^ u64::from(objects) << 8 ^ run as u64);
            let mut pending = lanes::Pending::<u32, u32>::default();
            let mut out = Batches::default();
            let mut items = Vec::new();
            let mut object = ObjectId(0);
            for n in 0..5_000u32 {
                if (n as usize).is_multiple_of(run) {
                    object = ObjectId(values.bits() % objects);
                }
                // The input names the item's object, to check the batch it lands in.
                pending.push(object, n, object.0, &mut out);
                items.push(n);
            }
            pending.finish(&mut out);
            let mut seen = Vec::new();
            for (object, batch) in &out.0 {
                assert!((1..=lanes::LANES).contains(&batch.len()));
                for &(to, input) in batch {
                    assert_eq!(input, object.0, "item {to} in a batch of another object");
                    seen.push(to);
                }
            }
            seen.sort_unstable();
            assert_eq!(seen, items, "{objects} objects, runs of {run}");
            // Runs of one object fill whole batches: only the last of each object's can be
            // short, plus those flushed to make room when more objects interleave than fit.
            let short = out.0.iter().filter(|(_, b)| b.len() < lanes::LANES).count();
            if objects <= 8 {
                assert!(short <= objects as usize, "{short} short batches");
            }
        }
    }
}

/// The walk's tests for rows of one object: due at every position while they pass; after
/// failures, `LANES` items later, then twice as many each time, up to sixteen rows; a pass
/// starts the back-off again.
#[test]
fn row_tests_back_off_after_failures_and_start_again_after_a_pass() {
    use lanes::{LANES, RowTests};
    let mut t = RowTests::from(5);
    assert!(!t.due(4) && t.due(5) && t.due(6));
    let mut at = 5;
    let mut gaps = Vec::new();
    for _ in 0..7 {
        t.failed(at);
        let next = (at..).find(|&i| t.due(i)).unwrap();
        gaps.push(next - at);
        at = next;
    }
    let l = LANES;
    assert_eq!(gaps, [l, 2 * l, 4 * l, 8 * l, 16 * l, 16 * l, 16 * l]);
    t.passed();
    assert!(t.due(at + 1), "due at every position after a pass");
    t.failed(at + 1);
    assert!(
        !t.due(at + LANES) && t.due(at + 1 + LANES),
        "the back-off starts again"
    );
}

#[test]
fn compacted_inserts_spread_over_the_view_at_their_touched_pixels() {
    // A 5×3 view: every pixel touched, none, runs that start at the first pixel or end at the
    // last, and a touched count that fills whole rows of the compacted inserts (no padding).
    let (w, h) = (5u32, 3u32);
    let pixels = (w * h) as usize;
    let masks: Vec<Vec<u32>> = vec![
        (0..15).collect(),
        vec![],
        vec![0, 1, 2, 7, 14],
        vec![3, 4, 5, 9, 10, 11, 12, 13, 14, 6],
        vec![14],
    ];
    let mut out = Vec::new();
    for touched in masks {
        let mask = PixelMask::from_fn(w * h, |p| touched.contains(&p));
        let t = mask.len();
        let rows = strata_wire::compact_height(t, w);
        // Touched pixel i holds i % 3 inserts; the padding none.
        let lens: Vec<u32> = (0..w * rows)
            .map(|i| if i < t { i % 3 } else { 0 })
            .collect();
        let compact = DeepFrame::build(w, rows, &lens, |i, run| {
            for k in 0..lens[i] {
                run.push(Fragment {
                    depth: 0.1 * (k + 1) as f32,
                    color: Rgba8([0; 4]),
                    object: ObjectId(1),
                });
            }
        })
        .unwrap();
        copy::spread_offsets(&mask, compact.offsets(), pixels, &mut out);
        // One pixel at a time: the i-th touched pixel's run is compacted run i.
        let mut want = vec![0u32];
        let mut i = 0;
        for p in 0..w * h {
            let n = if mask.iter().any(|q| q == p) {
                i += 1;
                lens[i - 1]
            } else {
                0
            };
            want.push(want.last().unwrap() + n);
        }
        assert_eq!(out, want, "touched {touched:?}");
        assert_eq!(*out.last().unwrap() as usize, compact.fragment_count());
    }
}
