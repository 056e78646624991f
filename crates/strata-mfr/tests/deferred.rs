//! Deferred shading: the SC's deep G-buffer plus the FC's normal fragments, lit by the current
//! lights, equal the whole scene's normal fragments lit by the same shader, bit for bit; and
//! shading a packed normal differs from shading the exact one by at most the packing's bound.

use glam::Vec3;
use proptest::prelude::*;
use strata_core::{DeepFrame, ObjectId, PackedNormal};
use strata_mfr::authority::{Authority, Snapshot};
use strata_mfr::client::Client;
use strata_mfr::deferred::{
    deferred_frame, deferred_image, deferred_reference, run_deferred_virtual,
};
use strata_mfr::lighting::{LightRig, LightingError, LightingModel, PointLight, Shader};
use strata_mfr::simulate::{Migration, VirtualClock};
use strata_mfr::trace::Trace;
use strata_mfr::trace::{GrabParams, grab};
use strata_raster::FragmentOutput;
use strata_scene::{Scene, SearchPath, open_scene};

const SIZE: (u32, u32) = (48, 36);

fn mixed() -> Scene {
    open_scene("mixed", &SearchPath::new(Vec::<std::path::PathBuf>::new())).expect("built-in scene")
}

fn normal_client() -> Client {
    Client::new(SIZE.0, SIZE.1).with_output(FragmentOutput::PackedNormal)
}

/// The snapshot with the FC's objects moved along a line with time: they are what the user drags.
fn posed(base: &Snapshot, fc: &[usize], t_ms: f64) -> Snapshot {
    let mut s = base.clone();
    for &i in fc {
        s.objects[i].offset = Vec3::new(0.3, -0.2, 0.1) * (t_ms / 300.0) as f32;
        s.objects[i].version = 1;
    }
    s
}

fn shader(scene: &Scene, snapshot: &Snapshot, lights: &[PointLight]) -> Shader {
    let projection = scene.camera.projection(SIZE.0, SIZE.1);
    Shader::new(
        scene,
        SIZE,
        snapshot.view.matrix(),
        projection,
        lights,
        LightingModel::default(),
    )
}

/// A virtual-clock run: the SC renders the whole scene every 5th FC frame (so its copies of the
/// FC's objects are stale), the FC renders its objects at their current pose every frame and
/// lights the composition with the lights of the FC frame's time. Every frame equals the whole
/// scene rendered at once as normal fragments and lit by the same shader.
#[test]
fn sc_plus_fc_deferred_equals_the_whole_scene_lit_by_the_same_shader_every_frame() {
    let scene = mixed();
    let authority = Authority::new(&scene, Trace::default());
    let base = authority.current();
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    let fc_objects = vec![1usize, 3];
    let mut fc_ids: Vec<ObjectId> = fc_objects.iter().map(|&i| scene.objects[i].id).collect();
    fc_ids.sort_unstable();
    let rig = LightRig::ring(4, Vec3::new(0.0, 1.0, 0.0), 2.5, 400.0);
    let (mut sc, mut fc, mut whole) = (normal_client(), normal_client(), normal_client());
    let fc_ms = 1000.0 / 60.0;
    let mut gbuffer: Option<DeepFrame> = None;
    let mut changed_pixels = 0usize;
    let mut previous_image = None;
    for frame in 0..12u32 {
        let t = f64::from(frame) * fc_ms;
        let now = posed(&base, &fc_objects, t);
        if frame % 5 == 0 {
            gbuffer = Some(
                sc.render(&scene, &now, &now.view, &all)
                    .expect("SC renders"),
            );
        }
        let sc_frame = gbuffer.as_ref().expect("the first frame renders the SC");
        let fc_frame = fc
            .render(&scene, &now, &now.view, &fc_objects)
            .expect("FC renders");
        let lights = rig.at(t);
        let shader = shader(&scene, &now, &lights);
        let deferred = deferred_frame(sc_frame, &fc_frame, &fc_ids, &shader).expect("deferred");
        let reference_normals = whole
            .render(&scene, &now, &now.view, &all)
            .expect("whole scene renders");
        let reference = shader.shade_frame(&reference_normals).expect("shades");
        assert_eq!(deferred, reference, "frame {frame}");
        assert!(
            deferred.fragment_count() > 0,
            "frame {frame} shows something"
        );
        let image = deferred_image(sc_frame, &fc_frame, &fc_ids, &shader, scene.background)
            .expect("deferred image");
        assert_eq!(image, reference.resolve(scene.background), "frame {frame}");
        if let Some(prev) = previous_image.replace(image.clone()) {
            changed_pixels += count_changed(&prev, &image);
        }
    }
    // The lights moved: the images change from frame to frame even between SC frames.
    assert!(changed_pixels > 100, "only {changed_pixels} pixels changed");
}

fn count_changed(a: &strata_core::Rgb8Image, b: &strata_core::Rgb8Image) -> usize {
    a.as_bytes()
        .chunks(3)
        .zip(b.as_bytes().chunks(3))
        .filter(|(x, y)| x != y)
        .count()
}

/// Between two SC frames the G-buffer is the same, and only the lights change: the FC's image
/// still follows them (the light-to-screen lag is the FC's).
#[test]
fn moving_lights_change_the_image_without_a_new_gbuffer() {
    let scene = mixed();
    let base = Authority::new(&scene, Trace::default()).current();
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    let gbuffer = normal_client()
        .render(&scene, &base, &base.view, &all)
        .expect("SC renders");
    let none = DeepFrame::empty(SIZE.0, SIZE.1);
    let rig = LightRig::ring(1, Vec3::new(0.0, 1.0, 0.0), 2.5, 400.0);
    let a = deferred_image(
        &gbuffer,
        &none,
        &[],
        &shader(&scene, &base, &rig.at(0.0)),
        [0.0; 3],
    )
    .expect("image");
    let b = deferred_image(
        &gbuffer,
        &none,
        &[],
        &shader(&scene, &base, &rig.at(200.0)),
        [0.0; 3],
    )
    .expect("image");
    assert!(count_changed(&a, &b) > 50);
}

#[test]
fn a_fragment_of_an_unknown_object_is_an_error() {
    let scene = mixed();
    let base = Authority::new(&scene, Trace::default()).current();
    let lists: Vec<Vec<strata_core::Fragment>> = (0..SIZE.0 * SIZE.1)
        .map(|p| {
            if p == 7 {
                vec![strata_core::Fragment {
                    depth: 0.5,
                    color: strata_core::Rgba8::from_bits(
                        PackedNormal::pack([0.0, 0.0, 1.0]).to_bits(),
                    ),
                    object: ObjectId(9999),
                }]
            } else {
                Vec::new()
            }
        })
        .collect();
    let frame = DeepFrame::from_pixel_lists(SIZE.0, SIZE.1, &lists).expect("a frame");
    let err = shader(&scene, &base, &[])
        .shade_frame(&frame)
        .expect_err("unknown object");
    assert!(matches!(err, LightingError::UnknownObject(9999)), "{err}");
    assert!(err.to_string().contains("9999"));
}

/// The largest angle between a unit normal and its packed-and-unpacked copy (strata-core's
/// round-trip bound).
const PACKING_ANGLE: f32 = 1.2e-4;

/// The bound on |deferred - forward| in 8-bit steps: a normal off by `δ` radians moves `N·L` and
/// `N·H` by at most `δ`, `(N·H)^s · N·L` by at most `(s + 1)·δ`, so each channel's unquantised
/// value by at most `255 · δ · Σ aᵢ cᵢ · (albedo + k_s · (s + 1))` (`aᵢ ≤ 1`, albedo ≤ 1), and
/// rounding adds at most one step.
fn forward_bound(lights: &[PointLight], model: &LightingModel) -> f32 {
    let c: f32 = lights
        .iter()
        .map(|l| l.color.iter().copied().fold(0.0, f32::max))
        .sum();
    (255.0 * PACKING_ANGLE * c * (1.0 + model.specular * (model.shininess + 1) as f32)).floor()
        + 1.0
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// Deferred shading (the packed normal) against forward shading (the exact normal), at the
    /// same eye position: within [`forward_bound`] — away from silhouettes, where the normal is
    /// within the packing's error of perpendicular to the view ray and two-sided lighting may
    /// flip it.
    #[test]
    fn deferred_is_within_the_packing_bound_of_forward(
        n in prop::array::uniform3(-1.0f32..1.0),
        p in prop::array::uniform3(-2.0f32..2.0),
        depth in 0.5f32..10.0,
        color in prop::array::uniform4(0.0f32..1.0),
        light_count in 1usize..=8,
        t in 0.0f64..1000.0,
    ) {
        let n = Vec3::from(n);
        prop_assume!(n.length() > 0.1);
        let n = n.normalize();
        let p = Vec3::new(p[0], p[1], -depth);
        let v = (-p).normalize();
        prop_assume!(n.dot(v).abs() > 2.0 * PACKING_ANGLE);
        let scene = mixed();
        let base = Authority::new(&scene, Trace::default()).current();
        let lights = LightRig::ring(light_count, Vec3::new(0.0, 1.0, 0.0), 2.5, 400.0).at(t);
        let shader = shader(&scene, &base, &lights);
        let packed = PackedNormal::pack(n.to_array()).unpack().map(Vec3::from);
        let forward = shader.shade(color, p, Some(n));
        let deferred = shader.shade(color, p, packed);
        let bound = forward_bound(&lights, &LightingModel::default());
        for k in 0..4 {
            let d = f32::from(forward.0[k].abs_diff(deferred.0[k]));
            prop_assert!(d <= bound, "channel {}: {:?} vs {:?}, bound {}", k, forward, deferred, bound);
        }
    }
}

/// The whole system on the virtual clock: an object grabbed and dragged (it migrates to the FC
/// and back), two lights keyed by the trace (one moving linearly, one on a circle): every FC
/// frame equals the whole scene's normal fragments lit by the same shader, bit for bit.
#[test]
fn a_virtual_clock_run_with_trace_lights_is_exact_in_every_frame() {
    let scene = mixed();
    let params = GrabParams {
        object: None,
        start_ms: 30.0,
        over_lead_ms: 60.0,
        hold_ms: 150.0,
        distance: 0.3,
        linger_ms: 30.0,
    };
    let grabbed = grab(&scene, &params).expect("a grab trace");
    let lights = Trace::from_toml(
        "lights",
        r#"
        [[event]]
        t_ms = 0
        light = { id = 0, position = [-2.0, 1.5, 1.0], color = [1.0, 0.9, 0.8] }
        [[event]]
        t_ms = 0
        light = { id = 1, circle = { center = [0.0, 1.0, 0.0], radius = 2.0, period_ms = 300 } }
        [[event]]
        t_ms = 300
        light = { id = 0, position = [2.0, 1.5, 1.0] }
        "#,
    )
    .expect("a light trace");
    let mut events: Vec<_> = grabbed
        .events()
        .iter()
        .chain(lights.events())
        .copied()
        .collect();
    events.sort_by(|a, b| a.t_ms.total_cmp(&b.t_ms));
    let trace = Trace::new(events).expect("in time order");
    let clock = VirtualClock {
        sc_ms: 60.0,
        fc_ms: 20.0,
        transfer_ms: 5.0,
    };
    let mut reference = normal_client();
    let (mut frames, mut with_fc, mut light_counts) = (0, 0, Vec::new());
    let fallback = LightRig::default();
    run_deferred_virtual(
        &scene,
        trace,
        clock,
        Migration::Predictive,
        &fallback,
        LightingModel::default(),
        SIZE,
        20,
        |f| {
            let expected = deferred_reference(&scene, &mut reference, f).expect("reference");
            assert_eq!(f.shaded, expected, "frame {}", f.index);
            assert_eq!(
                f.image,
                expected.resolve(scene.background),
                "frame {}",
                f.index
            );
            frames += 1;
            with_fc += usize::from(f.sc.is_some() && !f.fc_ids.is_empty());
            light_counts.push(f.lights.len());
        },
    )
    .expect("the run");
    assert_eq!(frames, 20);
    assert!(with_fc > 0, "the FC drew the grabbed object in some frames");
    assert!(light_counts.iter().all(|&n| n == 2), "{light_counts:?}");
}

#[test]
fn a_run_without_trace_lights_uses_the_rig() {
    let scene = mixed();
    let rig = LightRig::ring(3, Vec3::new(0.0, 1.0, 0.0), 2.0, 500.0);
    let clock = VirtualClock {
        sc_ms: 40.0,
        fc_ms: 20.0,
        transfer_ms: 0.0,
    };
    let mut counts = Vec::new();
    let cost = run_deferred_virtual(
        &scene,
        Trace::default(),
        clock,
        Migration::Predictive,
        &rig,
        LightingModel::default(),
        SIZE,
        4,
        |f| counts.push(f.lights.len()),
    )
    .expect("the run");
    assert_eq!(counts, [3, 3, 3, 3]);
    assert_eq!(cost.frames, 2);
    assert!(cost.max_fragments > 0);
}

#[test]
fn light_events_parse_from_json_lines_and_bad_ones_are_refused_clearly() {
    let ok = Trace::from_json_lines(
        "l.jsonl",
        r#"{"t_ms": 5, "light": {"id": 2, "position": [0, 1, 2], "range": 3}}"#,
    )
    .expect("a light event");
    assert_eq!(ok.events().len(), 1);
    let cases = [
        (
            r#"{"t_ms": 0, "light": {"id": 0, "position": [0, 1, 2], "circle": {"center": [0, 0, 0], "radius": 1, "period_ms": 9}}}"#,
            "exactly one of position, circle",
        ),
        (
            r#"{"t_ms": 0, "light": {"id": 0, "position": [0, 1, 2], "range": 0}}"#,
            "light.range 0 must be more than 0",
        ),
        (
            r#"{"t_ms": 0, "light": {"id": 0, "circle": {"center": [0, 0, 0], "radius": 1, "period_ms": 0}}}"#,
            "period_ms 0 must be more than 0",
        ),
        (
            r#"{"t_ms": 0, "light": {"id": 0, "position": [0, 1]}}"#,
            "light.position needs 3 numbers",
        ),
        (
            r#"{"t_ms": 0, "light": {"id": 0, "position": [0, 1, 2], "color": [1, -1, 0]}}"#,
            "must not be negative",
        ),
    ];
    for (line, words) in cases {
        let err = Trace::from_json_lines("l.jsonl", line).expect_err(line);
        assert!(err.to_string().contains(words), "{err} lacks {words}");
        assert!(err.to_string().contains("line 1"), "{err}");
    }
}
