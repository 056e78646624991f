//! Traces, the Fig. 6.5 states and the state authority's snapshots on a built-in scene.

use std::sync::Arc;

use glam::Vec3;
use proptest::prelude::*;
use strata_mfr::trace::{GrabParams, grab, orbit};
use strata_mfr::{Authority, Button, Event, Input, ObjectState, TimedEvent, Trace};
use strata_scene::{Scene, SearchPath, open_scene};

fn mixed() -> Scene {
    open_scene("mixed", &SearchPath::new(Vec::<std::path::PathBuf>::new())).expect("built-in scene")
}

fn index_of(scene: &Scene, name: &str) -> usize {
    scene
        .objects
        .iter()
        .position(|o| o.name == name)
        .expect("object in the scene")
}

/// Replays `trace` sampling every `step_ms`, returning every distinct snapshot.
fn replay(scene: &Scene, trace: Trace, step_ms: f64) -> Vec<Arc<strata_mfr::Snapshot>> {
    let end = trace.duration_ms() + 2.0 * step_ms;
    let mut a = Authority::new(scene, trace);
    let mut out = vec![a.current()];
    let mut t = 0.0;
    while t <= end {
        let s = a.advance_to(t);
        if s.id != out.last().expect("one").id {
            out.push(s);
        }
        t += step_ms;
    }
    assert!(a.finished());
    out
}

#[test]
fn grab_goes_inactive_over_selected_over_inactive_and_moves_the_object() {
    let scene = mixed();
    // The glass sphere is at the left of the scene; moving it further left keeps the pointer on
    // it after the release (OVER), until the pointer turns away (INACTIVE).
    let p = GrabParams {
        object: Some("glass sphere".into()),
        distance: -0.3,
        ..GrabParams::default()
    };
    let snaps = replay(&scene, grab(&scene, &p).expect("trace"), 10.0);
    let i = index_of(&scene, "glass sphere");
    // The sequence of states the grabbed object went through, without repeats.
    let mut states: Vec<ObjectState> = snaps.iter().map(|s| s.objects[i].state).collect();
    states.dedup();
    use ObjectState::*;
    assert_eq!(states, vec![Inactive, Over, Selected, Over, Inactive]);
    // Every other object stayed INACTIVE and in place.
    for s in &snaps {
        for (j, o) in s.objects.iter().enumerate() {
            if j != i {
                assert_eq!((o.state, o.offset, o.version), (Inactive, Vec3::ZERO, 0));
            }
        }
    }
    // It moved by the distance along the camera's right, and each move is a new version.
    let last = snaps.last().expect("snapshots");
    let moved = last.objects[i].offset;
    assert!((moved.length() - p.distance.abs()).abs() < 1e-5, "{moved}");
    let versions: Vec<u64> = snaps.iter().map(|s| s.objects[i].version).collect();
    assert!(versions.windows(2).all(|w| w[1] >= w[0]));
    assert!(
        *versions.last().expect("versions") >= 50,
        "about one step per 10 ms of a 1 s drag"
    );
    // Snapshot ids count up by one, times never go back.
    assert!(
        snaps
            .windows(2)
            .all(|w| w[1].id == w[0].id + 1 && w[1].t_ms >= w[0].t_ms)
    );
    // The selection lasted the hold time (the snapshot of the first SELECTED is at the button).
    let first = |st: ObjectState| {
        snaps
            .iter()
            .find(|s| s.objects[i].state == st)
            .map(|s| s.t_ms)
            .expect("state reached")
    };
    assert_eq!(first(Over), p.start_ms);
    assert_eq!(first(Selected), p.start_ms + p.over_lead_ms);
}

#[test]
fn the_nearest_object_under_the_ray_is_over_and_a_button_on_nothing_selects_nothing() {
    let scene = mixed();
    let eye = scene.camera.eye;
    let ev = |t_ms: f64, event: Event| TimedEvent { t_ms, event };
    // A ray from the eye through the scene centre passes the cube (at the centre) first.
    let through = (scene.camera.target - eye).normalize();
    let trace = Trace::new(vec![
        ev(0.0, Event::Button(Button::Down)),
        ev(10.0, Event::Button(Button::Up)),
        ev(
            20.0,
            Event::Pointer {
                origin: eye,
                dir: through,
            },
        ),
        ev(
            30.0,
            Event::Pointer {
                origin: eye,
                dir: -through,
            },
        ),
    ])
    .expect("in order");
    let mut a = Authority::new(&scene, trace);
    let s = a.advance_to(15.0);
    assert!(s.objects.iter().all(|o| o.state == ObjectState::Inactive));
    let s = a.advance_to(25.0);
    let over: Vec<&str> = s
        .objects
        .iter()
        .zip(&scene.objects)
        .filter(|(p, _)| p.state == ObjectState::Over)
        .map(|(_, o)| o.name.as_str())
        .collect();
    assert_eq!(over.len(), 1, "{over:?}");
    let s = a.advance_to(35.0);
    assert!(s.objects.iter().all(|o| o.state == ObjectState::Inactive));
    // Asking again at the same time changes nothing: the same snapshot.
    assert_eq!(a.advance_to(35.0).id, s.id);
}

#[test]
fn orbit_keeps_the_distance_and_height() {
    let scene = mixed();
    let trace = orbit(&scene, 1000.0, 1000.0, 50.0).expect("orbit");
    assert_eq!(trace.events().len(), 21);
    let d0 = scene.camera.eye.distance(scene.camera.target);
    for e in trace.events() {
        let Event::View { eye, target, .. } = e.event else {
            panic!("orbit makes view events");
        };
        assert!((eye.distance(target) - d0).abs() < 1e-4);
        assert!((eye.y - scene.camera.eye.y).abs() < 1e-5);
    }
    let Event::View { eye: last, .. } = trace.events()[20].event else {
        unreachable!()
    };
    assert!(last.distance(scene.camera.eye) < 1e-4, "one whole turn");
}

#[test]
fn toml_and_json_lines_read_the_same_trace() {
    let toml = r#"
[[event]]
t_ms = 0
view = { eye = [0.0, 0.5, 3.0], target = [0.0, 0.0, 0.0] }

[[event]]
t_ms = 400
pointer = { origin = [0.0, 0.5, 3.0], dir = [0.0, -0.1, -1.0] }

[[event]]
t_ms = 700
button = "down"

[[event]]
t_ms = 700
drag = { by = [0.3, 0.0, 0.0], duration_ms = 1000 }
"#;
    let jsonl = r#"{"t_ms": 0, "view": {"eye": [0.0, 0.5, 3.0], "target": [0.0, 0.0, 0.0]}}
# comments and blank lines are skipped

{"t_ms": 400, "pointer": {"origin": [0.0, 0.5, 3.0], "dir": [0.0, -0.1, -1.0]}}
{"t_ms": 700, "button": "down"}
{"t_ms": 700, "drag": {"by": [0.3, 0.0, 0.0], "duration_ms": 1000}}
"#;
    let a = Trace::from_toml("a.toml", toml).expect("toml");
    let b = Trace::from_json_lines("b.jsonl", jsonl).expect("json lines");
    assert_eq!(a, b);
    assert_eq!(a.events().len(), 4);
    assert_eq!(a.duration_ms(), 700.0);
}

#[test]
fn malformed_traces_say_what_and_where() {
    let cases: &[(&str, &[&str])] = &[
        (
            "[[event]]\nt_ms = 0\nbutton = \"down\"\npointer = { origin = [0,0,0], dir = [0,0,1] }\n",
            &["event 1 (line 1)", "2 kinds"],
        ),
        ("[[event]]\nt_ms = 0\n", &["event 1", "0 kinds"]),
        (
            "[[event]]\nt_ms = 5\nbutton = \"down\"\n[[event]]\nt_ms = 1\nbutton = \"up\"\n",
            &["event 2 (line 4)", "before", "time order"],
        ),
        ("[[event]]\nt_ms = -1\nbutton = \"up\"\n", &["t_ms -1"]),
        (
            "[[event]]\nt_ms = 0\nbutton = \"middle\"\n",
            &["line 3", "middle"],
        ),
        ("[[event]]\nt_ms = 0\nbuton = \"up\"\n", &["line", "buton"]),
        (
            "[[event]]\nt_ms = 0\npointer = { origin = [0,0,0], dir = [0,0,0] }\n",
            &["pointer.dir", "zero length"],
        ),
        (
            "[[event]]\nt_ms = 0\ndrag = { by = [1,0,0], duration_ms = 0 }\n",
            &["duration_ms 0"],
        ),
        (
            "[[event]]\nt_ms = 0\nview = { eye = [0,0,1,9], target = [0,0,0] }\n",
            &["event 1", "view.eye needs 3 numbers, found 4"],
        ),
    ];
    for (text, words) in cases {
        let err = Trace::from_toml("t.toml", text)
            .expect_err(text)
            .to_string();
        assert!(err.starts_with("t.toml: "), "{err}");
        for w in *words {
            assert!(err.contains(w), "expected {w:?} in {err:?}");
        }
    }
    let err = Trace::from_json_lines(
        "t.jsonl",
        "{\"t_ms\": 0, \"button\": \"up\"}\n{\"t_ms\": 1}\n",
    )
    .expect_err("no kind")
    .to_string();
    assert!(err.contains("line 2") && err.contains("0 kinds"), "{err}");
    let err = Trace::from_json_lines("t.jsonl", "not json\n")
        .expect_err("garbage")
        .to_string();
    assert!(err.contains("line 1"), "{err}");
}

#[test]
fn grab_parameters_are_checked() {
    let scene = mixed();
    let p = GrabParams::parse("object=glass torus,over_lead_ms=0,hold_ms=500").expect("valid");
    assert_eq!(p.over_lead_ms, 0.0);
    for (spec, word) in [
        ("over_lead_ms=-5", "over_lead_ms=-5"),
        ("speed=3", "unknown parameter 'speed'"),
        ("hold_ms", "key=value"),
        ("distance=nan", "distance=nan"),
    ] {
        let err = GrabParams::parse(spec).expect_err(spec).to_string();
        assert!(err.contains(word), "{err}");
    }
    let err = grab(
        &scene,
        &GrabParams {
            object: Some("no such".into()),
            ..GrabParams::default()
        },
    )
    .expect_err("unknown object")
    .to_string();
    assert!(
        err.contains("no object 'no such'") && err.contains("glass torus"),
        "{err}"
    );
}

fn any_input() -> impl Strategy<Value = Input> {
    prop_oneof![
        Just(Input::Intersect),
        Just(Input::NoIntersect),
        Just(Input::Select),
        Just(Input::Release),
    ]
}

proptest! {
    /// Fig. 6.5: over any input sequence the state moves only along the diagram's edges, SELECTED
    /// is reached only from OVER by Select and left only by Release (to OVER), and INACTIVE is
    /// reached only from OVER by No Intersect.
    #[test]
    fn states_move_only_along_fig_6_5(inputs in prop::collection::vec(any_input(), 0..64)) {
        use ObjectState::*;
        let mut s = Inactive;
        for input in inputs {
            let n = s.next(input);
            let edge = matches!(
                (s, input, n),
                (Inactive, Input::Intersect, Over)
                    | (Over, Input::NoIntersect, Inactive)
                    | (Over, Input::Select, Selected)
                    | (Selected, Input::Release, Over)
            );
            prop_assert!(edge || n == s, "{s:?} --{input:?}--> {n:?}");
            if n == Selected && s != Selected {
                prop_assert_eq!((s, input), (Over, Input::Select));
            }
            if s == Selected && n != Selected {
                prop_assert_eq!((input, n), (Input::Release, Over));
            }
            s = n;
        }
    }
}
