//! Deferred shading: the SC's deep G-buffer plus the FC's normal fragments, lit by the current
//! lights, equal the whole scene's normal fragments lit by the same shader, bit for bit; and
//! shading a packed normal differs from shading the exact one by at most the packing's bound.

use glam::Vec3;
use proptest::prelude::*;
use strata_core::{DeepFrame, ObjectId, PackedNormal};
use strata_mfr::authority::{Authority, Snapshot};
use strata_mfr::client::Client;
use strata_mfr::deferred::{
    DeferredError, ShadeOn, deferred_frame, deferred_image, deferred_reference, light_lag,
    run_deferred_virtual,
};
use strata_mfr::lighting::{LightingError, LightingModel, PointLight, Shader, TraceLights};
use strata_mfr::simulate::{Migration, VirtualClock};
use strata_mfr::timeline::FrameRecord;
use strata_mfr::trace::Trace;
use strata_mfr::trace::{Event, GrabParams, LightMotion, LightRingParams, grab, light_ring};
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

/// `count` lights of the built-in ring (400 ms a turn) where they are at `t_ms`.
fn ring(scene: &Scene, count: u32, t_ms: f64) -> Vec<PointLight> {
    let trace = light_ring(
        scene,
        &LightRingParams {
            count,
            period_ms: 400.0,
            duration_ms: 1000.0,
            step_ms: 10.0,
        },
    )
    .expect("a light ring");
    TraceLights::new(&trace)
        .at(t_ms)
        .into_iter()
        .map(|l| l.light)
        .collect()
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
        let lights = ring(&scene, 4, t);
        let shader = shader(&scene, &now, &lights);
        let deferred = deferred_frame(sc_frame, &fc_frame, &fc_ids, &shader).expect("deferred");
        let reference_normals = whole
            .render(&scene, &now, &now.view, &all)
            .expect("whole scene renders");
        let reference = shader.shade_shown(&reference_normals).expect("shades");
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
    let a = deferred_image(
        &gbuffer,
        &none,
        &[],
        &shader(&scene, &base, &ring(&scene, 1, 0.0)),
        [0.0; 3],
    )
    .expect("image");
    let b = deferred_image(
        &gbuffer,
        &none,
        &[],
        &shader(&scene, &base, &ring(&scene, 1, 200.0)),
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
        light_count in 1u32..=8,
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
        let lights = ring(&scene, light_count, t);
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
    run_deferred_virtual(
        &scene,
        trace,
        clock,
        Migration::Predictive,
        ShadeOn::Fc,
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
fn a_run_without_lights_is_refused() {
    let scene = mixed();
    let clock = VirtualClock {
        sc_ms: 40.0,
        fc_ms: 20.0,
        transfer_ms: 0.0,
    };
    let err = run_deferred_virtual(
        &scene,
        Trace::default(),
        clock,
        Migration::Predictive,
        ShadeOn::Fc,
        LightingModel::default(),
        SIZE,
        4,
        |_| {},
    )
    .expect_err("no lights");
    assert!(matches!(err, DeferredError::NoLights), "{err}");
    assert!(err.to_string().contains("no `light` events"), "{err}");
}

/// The ring generator keys every light at every step, on its circle, evenly spaced.
#[test]
fn the_light_ring_keys_every_light_on_its_circle() {
    let scene = mixed();
    let p = LightRingParams {
        count: 3,
        period_ms: 1200.0,
        duration_ms: 300.0,
        step_ms: 100.0,
    };
    let trace = light_ring(&scene, &p).expect("a ring");
    assert_eq!(
        trace.events().len(),
        4 * 3,
        "3 lights at 0, 100, 200 and 300 ms"
    );
    let cam = &scene.camera;
    let radius = (cam.eye - cam.target).length() * 0.6;
    let center = cam.target + Vec3::Y * radius * 0.5;
    let mut positions = Vec::new();
    for e in trace.events() {
        let Event::Light {
            id,
            motion: LightMotion::At(p),
            range,
            ..
        } = e.event
        else {
            panic!("not a keyed light: {e:?}");
        };
        assert!(id < 3);
        assert!(
            ((p - center).length() - radius).abs() < 1e-4 * radius,
            "{p} off the circle"
        );
        assert!((p.y - center.y).abs() < 1e-6);
        assert_eq!(range, radius);
        positions.push((e.t_ms, id, p));
    }
    // At 0 ms the lights are a third of a turn apart; 100 ms later each has turned 1/12.
    let at = |t: f64, id: u32| {
        positions
            .iter()
            .find(|k| k.0 == t && k.1 == id)
            .expect("a key")
            .2
    };
    let angle = |p: Vec3| (p.z - center.z).atan2(p.x - center.x);
    let third = std::f32::consts::TAU / 3.0;
    let d = (angle(at(0.0, 1)) - angle(at(0.0, 0))).rem_euclid(std::f32::consts::TAU);
    assert!((d - third).abs() < 1e-4, "{d}");
    let d = (angle(at(100.0, 0)) - angle(at(0.0, 0))).rem_euclid(std::f32::consts::TAU);
    assert!((d - third / 4.0).abs() < 1e-4, "{d}");
    for (spec, words) in [
        ("count=0", "expected 1 to 64 lights"),
        ("step_ms=0", "more than 0"),
        ("speed=3", "unknown parameter 'speed'"),
        ("count", "expected key=value"),
    ] {
        let err = LightRingParams::parse(spec).expect_err(spec);
        assert!(err.to_string().contains(words), "{err} lacks {words}");
    }
    let huge = LightRingParams {
        step_ms: 0.001,
        duration_ms: 1e6,
        ..p
    };
    assert!(
        light_ring(&scene, &huge)
            .expect_err("too many keys")
            .to_string()
            .contains("at most a million")
    );
}

#[test]
fn merged_traces_keep_every_event_in_time_order() {
    let scene = mixed();
    let grabbed = grab(&scene, &GrabParams::default()).expect("a grab");
    let lights = light_ring(&scene, &LightRingParams::default()).expect("a ring");
    let both = grabbed.merged(&lights);
    assert_eq!(
        both.events().len(),
        grabbed.events().len() + lights.events().len()
    );
    assert!(both.events().windows(2).all(|w| w[0].t_ms <= w[1].t_ms));
    assert!(both.has_lights() && !grabbed.has_lights());
    // Trace::new accepts it: it is in order.
    Trace::new(both.events().to_vec()).expect("in time order");
}

/// Deferred against forward on one trace: the deferred frames equal the whole scene lit by the
/// frame's lights in every frame; the forward frames (the SC lights its own objects with the
/// lights of the state it renders) differ while the lights move and the SC lags, and match
/// again once the lights stop and the SC has caught up. The measured light-to-screen lag is one
/// FC frame deferred, the SC path forward.
#[test]
fn lights_reach_the_screen_at_the_fc_rate_deferred_and_the_sc_rate_forward() {
    let scene = mixed();
    let p = LightRingParams {
        count: 2,
        period_ms: 400.0,
        duration_ms: 200.0,
        step_ms: 40.0,
    };
    let trace = light_ring(&scene, &p).expect("a ring");
    let clock = VirtualClock {
        sc_ms: 80.0,
        fc_ms: 20.0,
        transfer_ms: 0.0,
    };
    let frames = 24;
    let mut lags = Vec::new();
    let mut bad_frames = Vec::new();
    for shade_on in [ShadeOn::Fc, ShadeOn::Sc] {
        let mut reference = normal_client();
        let mut records = Vec::new();
        let mut bad = Vec::new();
        run_deferred_virtual(
            &scene,
            trace.clone(),
            clock,
            Migration::Predictive,
            shade_on,
            LightingModel::default(),
            SIZE,
            frames,
            |f| {
                let expected = deferred_reference(&scene, &mut reference, f).expect("reference");
                bad.push(f.image != expected.resolve(scene.background));
                if shade_on == ShadeOn::Fc {
                    assert_eq!(f.shaded, expected, "frame {}", f.index);
                }
                records.push(FrameRecord::from_parts(
                    f.index,
                    f.t_ms,
                    f.t_ms + clock.fc_ms,
                    &f.snapshot,
                    f.sc.as_deref(),
                    None,
                ));
            },
        )
        .expect("the run");
        lags.push(light_lag(&trace, &records, shade_on));
        bad_frames.push(bad);
    }
    assert!(
        bad_frames[0].iter().all(|&b| !b),
        "deferred is exact: {:?}",
        bad_frames[0]
    );
    let forward = &bad_frames[1];
    assert!(
        forward.iter().filter(|&&b| b).count() >= 3,
        "forward lags: {forward:?}"
    );
    assert!(
        !forward[frames as usize - 1],
        "forward catches up once the lights stop"
    );
    let (deferred, forward) = (&lags[0], &lags[1]);
    assert_eq!(deferred.not_shown, 0);
    assert_eq!(deferred.shown_ms.len(), trace.events().len());
    assert!(
        deferred.shown_ms.iter().all(|&ms| ms == clock.fc_ms),
        "{:?}",
        deferred.shown_ms
    );
    // Forward: an SC frame starts every 80 ms and is delivered 80 ms later, then shown one FC
    // frame later: at least 100 ms after a key, up to 80 ms more when the key just missed a start.
    assert!(
        forward
            .shown_ms
            .iter()
            .all(|&ms| (100.0..=180.0).contains(&ms)),
        "{:?}",
        forward.shown_ms
    );
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

/// Lighting only what can show: the fragments behind each pixel's first opaque one are dropped,
/// the rest are lit exactly as before, and the image does not change by a bit.
#[test]
fn shading_only_the_fragments_that_show_keeps_the_image() {
    let scene = mixed();
    let base = Authority::new(&scene, Trace::default()).current();
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    let normals = normal_client()
        .render(&scene, &base, &base.view, &all)
        .expect("renders");
    let shader = shader(&scene, &base, &ring(&scene, 3, 50.0));
    let every = shader.shade_frame(&normals).expect("shades");
    let shown = shader.shade_shown(&normals).expect("shades");
    assert_eq!(
        shown.resolve(scene.background),
        every.resolve(scene.background)
    );
    assert!(
        shown.fragment_count() < every.fragment_count(),
        "the scene has fragments behind opaque ones: {} of {}",
        shown.fragment_count(),
        every.fragment_count()
    );
    let mut dropped = 0;
    for p in 0..(SIZE.0 * SIZE.1) as usize {
        let (a, b) = (every.run(p), shown.run(p));
        // A prefix of the same fragments, lit the same.
        assert_eq!(a.depth[..b.len()], *b.depth, "pixel {p}");
        assert_eq!(a.color[..b.len()], *b.color, "pixel {p}");
        if b.len() < a.len() {
            dropped += 1;
            assert_eq!(
                b.color[b.len() - 1].alpha(),
                255,
                "pixel {p} ends on an opaque fragment"
            );
            assert!(b.color[..b.len() - 1].iter().all(|c| c.alpha() < 255));
        }
    }
    assert!(dropped > 0);
}
