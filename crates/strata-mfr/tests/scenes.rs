//! The built-in multi-frame-rate scenes under the three compositions: `mfr-cars` (an FC part
//! dragged behind the SC's transparent windscreen, Springer 2008 fig. 6.6) and `mfr-engine` (a
//! part of the translucent engine glTF); and `grab`'s choice of a default object.

use std::sync::Arc;

use strata_core::{DeepFrame, ObjectId};
use strata_mfr::client::Client;
use strata_mfr::trace::{GrabParams, grab};
use strata_mfr::{
    Authority, Composition, FcFrame, FrameAudit, Migration, ObjectState, Snapshot, Trace,
    VirtualClock, audit, run_virtual,
};
use strata_scene::scene::file::{SceneOrigin, parse};
use strata_scene::{Scene, SearchPath, open_scene};

/// Small enough for tests, large enough for the steering wheel to cover a few dozen pixels.
const SIZE: (u32, u32) = (96, 54);

fn no_models() -> SearchPath {
    SearchPath::new(Vec::<std::path::PathBuf>::new())
}

fn id_of(scene: &Scene, name: &str) -> ObjectId {
    scene
        .objects
        .iter()
        .find(|o| o.name == name)
        .map(|o| o.id)
        .unwrap_or_else(|| panic!("no object '{name}' in {}", scene.name))
}

/// FC frames enough to see the whole trace and the SC catch up after it.
fn frames_for(trace: &Trace, clock: &VirtualClock) -> u64 {
    ((trace.duration_ms() + 3.0 * clock.sc_ms + clock.transfer_ms) / clock.fc_ms).ceil() as u64 + 1
}

/// The whole scene rendered at once, at the frame's snapshot, through the view it composed with.
fn reference(scene: &Scene, client: &mut Client, f: &FcFrame) -> DeepFrame {
    let view = f.sc.as_ref().map_or(f.snapshot.view, |sc| sc.view);
    let all: Vec<usize> = (0..scene.objects.len()).collect();
    client
        .render(scene, &f.snapshot, &view, &all)
        .expect("reference renders")
}

/// Whether some pixel of `frame` holds a fragment of another object in front of one of `part`'s.
fn behind_another_object(frame: &DeepFrame, part: ObjectId) -> bool {
    (0..frame.offsets().len() - 1).any(|p| {
        let objects = frame.run(p).object;
        objects
            .iter()
            .position(|&o| o == part)
            .is_some_and(|first| first > 0)
    })
}

/// One audited FC frame.
struct Audited {
    t_ms: f64,
    audit: FrameAudit,
    /// The composed frame equals the single renderer's, fragment for fragment.
    exact: bool,
    /// The image equals the single renderer's, pixel for pixel.
    same_image: bool,
    /// In the single renderer's frame, another object lies in front of the grabbed part.
    part_behind: bool,
}

impl Audited {
    fn artefacts(&self) -> u64 {
        self.audit.bad_pixels
            + self.audit.ghost_pixels
            + self.audit.hole_pixels
            + self.audit.blend_pixels
    }
}

/// Runs `trace` on `scene` and audits every FC frame against the single renderer; the reference
/// frames are rendered once and reused by the later runs of the same trace (`cache`), since the
/// snapshot and the view of frame `i` do not depend on the composition.
fn run_audited(
    scene: &Scene,
    trace: &Trace,
    clock: VirtualClock,
    composition: Composition,
    part: ObjectId,
    cache: &mut Vec<DeepFrame>,
) -> Vec<Audited> {
    let mut refs = Client::new(SIZE.0, SIZE.1);
    let mut out = Vec::new();
    let frames = frames_for(trace, &clock);
    run_virtual(
        scene,
        trace.clone(),
        clock,
        Migration::Predictive,
        composition,
        SIZE,
        frames,
        |f| {
            let i = f.index as usize;
            if cache.len() == i {
                cache.push(reference(scene, &mut refs, f));
            }
            let r = &cache[i];
            let composed = f.composed().expect("composes");
            assert_eq!(
                f.image,
                composed.resolve(scene.background),
                "{composition:?}, frame {i}: the image is the composed run's resolve"
            );
            out.push(Audited {
                t_ms: f.t_ms,
                audit: audit(&composed, r, scene.background),
                exact: composed == *r,
                same_image: f.image == r.resolve(scene.background),
                part_behind: behind_another_object(r, part),
            });
        },
    )
    .expect("the run completes");
    out
}

fn mfr_cars() -> Scene {
    open_scene("mfr-cars", &no_models()).expect("built-in scene")
}

/// Replays `trace`, returning the objects that were ever SELECTED (indices).
fn selected_objects(scene: &Scene, trace: Trace) -> Vec<usize> {
    let end = trace.duration_ms() + 20.0;
    let mut a = Authority::new(scene, trace);
    let mut selected = Vec::new();
    let mut t = 0.0;
    while t <= end {
        let s: Arc<Snapshot> = a.advance_to(t);
        for (i, o) in s.objects.iter().enumerate() {
            if o.state == ObjectState::Selected && !selected.contains(&i) {
                selected.push(i);
            }
        }
        t += 10.0;
    }
    selected
}

#[test]
fn mfr_cars_is_heavy_and_grab_takes_the_steering_wheel_by_default() {
    let scene = mfr_cars();
    let wheel = id_of(&scene, "steering wheel");
    let windscreen = id_of(&scene, "windscreen");
    assert!(scene.objects.len() > 100, "{} objects", scene.objects.len());
    assert!(
        scene.triangle_count() > 300_000,
        "{}",
        scene.triangle_count()
    );
    // The windscreen is transparent and the steering wheel opaque: the fig. 6.6 situation.
    let material = |id: ObjectId| scene.objects[id.0 as usize].material.color;
    assert!(material(windscreen)[3] < 1.0);
    assert_eq!(material(wheel)[3], 1.0);
    let trace = grab(&scene, &GrabParams::default()).expect("default grab");
    assert_eq!(
        selected_objects(&scene, trace),
        [wheel.0 as usize],
        "the default grab selects the steering wheel and nothing else"
    );
}

/// The fig. 6.6 situation on `mfr-cars`: the FC drags the opaque steering wheel into the cabin,
/// behind the SC's transparent windscreen. With a lead long enough that every SC buffer in use
/// after the grab has left the wheel out, the only artefacts left are those of the composition:
/// digital composition loses the wheel behind the windscreen and optical composition draws it
/// over the windscreen, in frames where the wheel is behind another object and only there; deep
/// composition equals the single renderer in every frame.
#[test]
fn mfr_cars_wheel_behind_the_windscreen_breaks_digital_and_optical_but_not_deep() {
    let scene = mfr_cars();
    let wheel = id_of(&scene, "steering wheel");
    let clock = VirtualClock {
        sc_ms: 200.0,
        fc_ms: 25.0,
        transfer_ms: 10.0,
    };
    let params = GrabParams {
        over_lead_ms: 2.0 * clock.sc_ms + clock.transfer_ms + 40.0,
        hold_ms: 500.0,
        linger_ms: 100.0,
        ..GrabParams::default()
    };
    let trace = grab(&scene, &params).expect("default grab");
    let mut cache = Vec::new();

    let deep = run_audited(&scene, &trace, clock, Composition::Deep, wheel, &mut cache);
    let inexact: Vec<f64> = deep.iter().filter(|a| !a.exact).map(|a| a.t_ms).collect();
    assert!(inexact.is_empty(), "deep: frames off at {inexact:?} ms");
    assert!(deep.iter().all(|a| a.artefacts() == 0));
    let behind = deep.iter().filter(|a| a.part_behind).count();
    assert!(behind > 0, "the wheel never passed behind the windscreen");

    for composition in [Composition::Digital, Composition::Optical] {
        let frames = run_audited(&scene, &trace, clock, composition, wheel, &mut cache);
        let off: Vec<&Audited> = frames.iter().filter(|a| a.audit.bad_pixels > 0).collect();
        assert!(
            !off.is_empty(),
            "{composition:?}: no bad pixel while the wheel is behind the windscreen"
        );
        let unexplained: Vec<f64> = frames
            .iter()
            .filter(|a| a.artefacts() > 0 && !a.part_behind)
            .map(|a| a.t_ms)
            .collect();
        assert!(
            unexplained.is_empty(),
            "{composition:?}: artefacts with the wheel in front of everything, at {unexplained:?} ms"
        );
        let wrong_kind = off.iter().filter(|a| match composition {
            // The wheel is lost: the field behind shows through (a hole and a ghost).
            Composition::Digital => a.audit.hole_pixels == 0,
            // The wheel is drawn untinted over the windscreen (a blend) or hides it (a hole).
            _ => a.audit.blend_pixels + a.audit.hole_pixels == 0,
        });
        assert_eq!(wrong_kind.count(), 0, "{composition:?}");
    }
}

/// Optical composition is exact while the FC's object is in front of everything the SC draws:
/// the steering wheel dragged away from the car, with a lead long enough that no SC buffer in
/// use shows a stale copy of it.
#[test]
fn optical_composition_is_exact_with_the_fc_object_in_front() {
    let scene = mfr_cars();
    let wheel = id_of(&scene, "steering wheel");
    let clock = VirtualClock {
        sc_ms: 200.0,
        fc_ms: 40.0,
        transfer_ms: 0.0,
    };
    let params = GrabParams {
        over_lead_ms: 2.0 * clock.sc_ms + 40.0,
        hold_ms: 400.0,
        distance: -0.3,
        linger_ms: 100.0,
        ..GrabParams::default()
    };
    let trace = grab(&scene, &params).expect("default grab");
    let frames = run_audited(
        &scene,
        &trace,
        clock,
        Composition::Optical,
        wheel,
        &mut Vec::new(),
    );
    assert!(
        frames.iter().all(|a| !a.part_behind),
        "the wheel stays in front"
    );
    // While the SC buffer still holds the wheel, the FC's copy covers the SC's (opaque, in the
    // same place): more fragments than the reference, the same image.
    let off: Vec<f64> = frames
        .iter()
        .filter(|a| !a.same_image || a.artefacts() > 0)
        .map(|a| a.t_ms)
        .collect();
    assert!(off.is_empty(), "optical: frames off at {off:?} ms");
    assert!(
        frames.iter().any(|a| !a.exact),
        "the SC's copy under the FC's"
    );
}

/// `grab` without an object takes the first object in scene order that a ray from the eye
/// reaches: an object listed first but hidden behind an opaque wall is passed over.
#[test]
fn grab_by_default_skips_objects_hidden_from_the_eye() {
    let text = r#"
        [camera]
        eye = [0.0, 0.0, 3.0]

        [[objects]]
        name = "hidden ball"
        builtin = "sphere"
        scale = 0.3
        translate = [0.0, 0.0, -1.0]

        [[objects]]
        name = "wall"
        builtin = "cube"
        color = [0.5, 0.5, 0.5, 1.0]
        scale = [2.0, 2.0, 0.1]
    "#;
    let scene = parse(text, SceneOrigin::Builtin("hidden"), &no_models()).expect("scene");
    let trace = grab(&scene, &GrabParams::default()).expect("the wall can be grabbed");
    assert_eq!(
        selected_objects(&scene, trace),
        [1],
        "the wall, not the ball"
    );
    let err = grab(
        &scene,
        &GrabParams {
            object: Some("hidden ball".into()),
            ..GrabParams::default()
        },
    )
    .expect_err("hidden")
    .to_string();
    assert!(
        err.contains("'hidden ball' is hidden from the eye"),
        "{err}"
    );
}

/// The engine glTF with one object per mesh node: a lifter of the translucent engine (its
/// pistons sit inside the cylinders, where no ray from outside reaches them) grabbed and dragged
/// at once, through and past the translucent parts. Deep composition with predictive migration
/// equals the single renderer in every frame; digital composition does not.
#[test]
fn mfr_engine_deep_is_exact_and_digital_is_not() {
    let Some(models) = strata_testdata::models(&["2CylinderEngine.glb"]) else {
        return;
    };
    let scene = open_scene("mfr-engine", &SearchPath::new(models.dirs())).expect("mfr-engine");
    let lifter = "engine/Lifter_123-923_0_Parts_1";
    let part = id_of(&scene, lifter);
    // Every mesh node is its own object with a unique name.
    let mut names: Vec<&str> = scene.objects.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(names.len(), 67);
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), 67, "names are unique");
    // The default grab takes the lifter: the parts listed before it are hidden from the eye.
    let default = grab(&scene, &GrabParams::default()).expect("default grab");
    assert_eq!(selected_objects(&scene, default), [part.0 as usize]);

    let clock = VirtualClock {
        sc_ms: 100.0,
        fc_ms: 20.0,
        transfer_ms: 10.0,
    };
    let params = GrabParams {
        object: Some(lifter.into()),
        start_ms: 20.0,
        over_lead_ms: 0.0,
        hold_ms: 300.0,
        distance: 0.3,
        linger_ms: 60.0,
    };
    let trace = grab(&scene, &params).expect("grab the lifter");
    let mut cache = Vec::new();
    let deep = run_audited(&scene, &trace, clock, Composition::Deep, part, &mut cache);
    let inexact: Vec<f64> = deep.iter().filter(|a| !a.exact).map(|a| a.t_ms).collect();
    assert!(inexact.is_empty(), "deep: frames off at {inexact:?} ms");
    let digital = run_audited(
        &scene,
        &trace,
        clock,
        Composition::Digital,
        part,
        &mut cache,
    );
    let off = digital.iter().filter(|a| a.audit.bad_pixels > 0).count();
    assert!(
        off > 0,
        "digital composition shows no artefact on the engine"
    );
}
