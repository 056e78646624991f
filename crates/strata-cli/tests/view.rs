//! `strata view` as a process: the page and its assets over HTTP, and the WebSocket protocol
//! spoken by a plain client (the browser tests in tests/browser drive the page itself).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command as StdCommand, Stdio};

use assert_cmd::Command;
use assert_cmd::cargo::CommandCargoExt;
use serde_json::{Value, json};
use tempfile::TempDir;
use tungstenite::Message;

mod common;

use common::Service;

/// A `strata view` process on a free port, killed when dropped.
struct Viewer {
    child: Child,
    addr: String,
}

impl Viewer {
    fn start(args: &[&str]) -> Viewer {
        Viewer::start_scene("spheres", args)
    }

    fn start_scene(scene: &str, args: &[&str]) -> Viewer {
        let mut child = StdCommand::cargo_bin("strata")
            .expect("the strata binary")
            .args(["view", scene, "--listen", "127.0.0.1:0", "-j", "2"])
            .args(args)
            .stderr(Stdio::piped())
            .spawn()
            .expect("strata view starts");
        let mut line = String::new();
        BufReader::new(child.stderr.take().expect("stderr"))
            .read_line(&mut line)
            .expect("a first line");
        let addr = line
            .split("http://")
            .nth(1)
            .and_then(|rest| rest.split('/').next())
            .unwrap_or_else(|| panic!("the first line names the address: {line:?}"))
            .to_owned();
        Viewer { child, addr }
    }

    fn get(&self, path: &str) -> (String, String) {
        let mut s = TcpStream::connect(&self.addr).expect("connect");
        write!(
            s,
            "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
        )
        .expect("send");
        let mut text = String::new();
        s.read_to_string(&mut text).expect("read");
        let (head, body) = text.split_once("\r\n\r\n").expect("a header and a body");
        (head.to_owned(), body.to_owned())
    }

    fn socket(&self) -> Socket {
        tungstenite::connect(format!("ws://{}/ws", self.addr))
            .expect("WebSocket handshake")
            .0
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        self.child.kill().ok();
        self.child.wait().ok();
    }
}

type Socket = tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>;

/// The next message that is not a ping or a pong (the server pings quiet pages).
fn next(ws: &mut Socket) -> tungstenite::Result<Message> {
    loop {
        match ws.read()? {
            Message::Ping(_) | Message::Pong(_) => continue,
            m => return Ok(m),
        }
    }
}

fn text(m: Message) -> Value {
    match m {
        Message::Text(t) => serde_json::from_str(&t).expect("JSON"),
        other => panic!("expected text, got {other:?}"),
    }
}

/// Splits a frame message into its header and PNG.
fn frame(m: Message) -> (Value, Vec<u8>) {
    let Message::Binary(b) = m else {
        panic!("expected a frame, got {m:?}");
    };
    let n = u32::from_le_bytes(b[..4].try_into().expect("length")) as usize;
    let header = serde_json::from_slice(&b[4..4 + n]).expect("header JSON");
    (header, b[4 + n..].to_vec())
}

fn pixels(png_bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(png_bytes))
        .read_info()
        .expect("a PNG");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buf).expect("a frame");
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn the_page_and_its_assets_are_served() {
    let v = Viewer::start(&[]);
    for (path, kind, needle) in [
        ("/", "text/html", "<canvas id=\"frame\""),
        ("/page.js", "text/javascript", "new WebSocket"),
        ("/page.css", "text/css", "#panel"),
    ] {
        let (head, body) = v.get(path);
        assert!(head.starts_with("HTTP/1.1 200"), "{path}: {head}");
        assert!(head.contains(kind), "{path}: {head}");
        assert!(body.contains(needle), "{path}");
    }
    let (head, _) = v.get("/nothing-here");
    assert!(head.starts_with("HTTP/1.1 404"), "{head}");
}

#[test]
fn a_view_request_gets_the_frame_strata_render_makes() {
    let v = Viewer::start(&["--method", "kbuffer:k=3"]);
    let mut ws = v.socket();
    let hello = text(next(&mut ws).expect("hello"));
    assert_eq!(hello["type"], "hello");
    assert_eq!(hello["scene"], "spheres");
    assert_eq!(hello["method"], "kbuffer");
    assert_eq!(hello["method_options"], json!({"k": "3"}));
    let kbuffer = hello["methods"]
        .as_array()
        .expect("methods")
        .iter()
        .find(|m| m["name"] == "kbuffer")
        .expect("kbuffer is offered");
    assert_eq!(kbuffer["options"], json!(["k", "tail-blend"]));
    let k = hello["options"]
        .as_array()
        .expect("options")
        .iter()
        .find(|o| o["name"] == "k")
        .expect("k is described");
    assert_eq!(k["default"], "4");
    assert!(k["help"].as_str().expect("help").contains("1 to 1024"));

    let camera = json!({"eye": [0.3, 0.5, 1.7], "target": [0, 0, 0], "up": [0, 1, 0],
                        "fovy_deg": 40, "near": 0.01, "far": 100});
    let request = json!({"type": "view", "id": 5, "width": 96, "height": 64, "camera": camera,
                         "method": "kbuffer", "options": {"k": "3"}});
    ws.send(Message::text(request.to_string())).expect("send");
    let (header, png) = frame(next(&mut ws).expect("a frame"));
    assert_eq!(header["id"], 5);
    assert_eq!(header["stats"]["method"], "kbuffer");
    let (w, h, got) = pixels(&png);
    assert_eq!((w, h), (96, 64));

    // The view the frame reports, pasted into the built-in scene's file, renders the same
    // image and the same statistics.
    let dir = TempDir::new().expect("temp dir");
    let scene = dir.path().join("view.toml");
    let out = dir.path().join("render.png");
    let stats = dir.path().join("render.json");
    // The built-in scene's own objects: render it with the page's view through a scene file.
    let source = Command::cargo_bin("strata")
        .expect("strata")
        .args(["scenes", "--print", "spheres"])
        .output()
        .expect("runs");
    let source = String::from_utf8(source.stdout).expect("utf-8");
    let objects = &source[source.find("[[objects]]").expect("objects")..];
    let view = header["camera_toml"].as_str().expect("camera_toml");
    let (size, cam) = view.split_once("[camera]").expect("a camera table");
    let background = "background = [1.0, 1.0, 1.0]\n";
    std::fs::write(
        &scene,
        format!("{size}{background}\n[camera]{cam}\n{objects}"),
    )
    .expect("write");
    Command::cargo_bin("strata")
        .expect("strata")
        .args([
            "render",
            scene.to_str().expect("utf-8"),
            "-m",
            "kbuffer",
            "-k",
            "3",
            "-j",
            "1",
        ])
        .arg("--out")
        .arg(&out)
        .arg("--stats")
        .arg(&stats)
        .assert()
        .success();
    let (_, _, expected) = pixels(&std::fs::read(&out).expect("render output"));
    assert!(
        got == expected,
        "the frame differs from strata render's image"
    );
    let cli: Value = serde_json::from_slice(&std::fs::read(&stats).expect("stats")).expect("JSON");
    for key in [
        "fragments",
        "covered_pixels",
        "depth_histogram",
        "memory_bytes",
    ] {
        assert_eq!(header["stats"][key], cli[key], "{key}");
    }
}

#[test]
fn bad_requests_get_errors_and_the_connection_goes_on() {
    let v = Viewer::start(&[]);
    let mut ws = v.socket();
    let hello = text(next(&mut ws).expect("hello"));
    let camera = hello["camera"].clone();
    let inspect =
        |x: u32, y: u32| Message::text(json!({"type": "inspect", "x": x, "y": y}).to_string());
    ws.send(inspect(0, 0)).expect("send");
    assert!(
        text(next(&mut ws).expect("a reply"))["message"]
            .as_str()
            .expect("message")
            .contains("no frame yet")
    );
    for (message, expected) in [
        ("not json".to_owned(), "malformed message"),
        (
            json!({"type": "view", "id": 9, "width": 0, "height": 10, "camera": camera,
                   "method": "abuffer"})
            .to_string(),
            "width 0",
        ),
        (
            json!({"type": "view", "id": 10, "width": 10, "height": 10, "camera": camera,
                   "method": "abuffer", "options": {"k": "2"}})
            .to_string(),
            "does not take k",
        ),
    ] {
        ws.send(Message::text(message)).expect("send");
        let reply = text(next(&mut ws).expect("a reply"));
        assert_eq!(reply["type"], "error");
        assert!(
            reply["message"]
                .as_str()
                .expect("message")
                .contains(expected),
            "{reply}"
        );
    }
    ws.send(Message::binary(vec![1, 2, 3])).expect("send");
    assert!(
        text(next(&mut ws).expect("a reply"))["message"]
            .as_str()
            .expect("message")
            .contains("binary")
    );
    // Still served.
    ws.send(Message::text(
        json!({"type": "view", "id": 11, "width": 8, "height": 8, "camera": camera,
               "method": "abuffer"})
        .to_string(),
    ))
    .expect("send");
    let (header, _) = frame(next(&mut ws).expect("a frame"));
    assert_eq!(header["id"], 11);
    ws.send(inspect(8, 0)).expect("send");
    let reply = text(next(&mut ws).expect("a reply"));
    assert!(
        reply["message"]
            .as_str()
            .expect("message")
            .contains("outside the 8x8 frame"),
        "{reply}"
    );
    ws.send(inspect(7, 7)).expect("send");
    let reply = text(next(&mut ws).expect("a reply"));
    assert_eq!(
        (reply["type"].as_str(), reply["frame"].as_u64()),
        (Some("pixel"), Some(11)),
        "{reply}"
    );
    assert_eq!(
        (reply["x"].as_u64(), reply["y"].as_u64()),
        (Some(7), Some(7))
    );
}

fn refused(args: &[&str], expected: &str) {
    let out = Command::cargo_bin("strata")
        .expect("strata")
        .args(args)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
    assert!(stderr.contains(expected), "{args:?}: {stderr}");
}

#[test]
fn a_bad_method_spec_or_address_is_refused_before_serving() {
    refused(
        &["view", "spheres", "--method", "kbuffer:budget=50%"],
        "does not take budget",
    );
    refused(
        &["view", "spheres", "--method", "nope"],
        "unknown method 'nope'",
    );
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = taken.local_addr().expect("address").to_string();
    refused(
        &["view", "spheres", "--listen", &addr],
        &format!("cannot listen on {addr}"),
    );
}

#[test]
fn a_compared_view_carries_the_reference_and_the_maps() {
    let v = Viewer::start(&[]);
    let mut ws = v.socket();
    let hello = text(next(&mut ws).expect("hello"));
    ws.send(Message::text(
        json!({"type": "view", "id": 1, "width": 40, "height": 150, "camera": hello["camera"],
               "method": "kbuffer", "options": {"k": "1"},
               "compare": {"method": "abuffer", "flip": true}})
        .to_string(),
    ))
    .expect("send");
    let Message::Binary(b) = next(&mut ws).expect("a frame") else {
        panic!("expected a frame");
    };
    let n = u32::from_le_bytes(b[..4].try_into().expect("length")) as usize;
    let header: Value = serde_json::from_slice(&b[4..4 + n]).expect("header JSON");
    // Each image in two bands of 75 rows (two threads, 150 rows), PNGs stacked top to bottom.
    let images = header["images"].as_array().expect("images");
    let names: Vec<&str> = images
        .iter()
        .map(|i| i["name"].as_str().expect("name"))
        .collect();
    assert_eq!(
        names,
        [
            "main",
            "main",
            "reference",
            "reference",
            "bad",
            "bad",
            "flip",
            "flip"
        ]
    );
    let mut at = 4 + n;
    let mut stacked: Vec<(&str, Vec<u8>)> = Vec::new();
    for image in images {
        let bytes = image["bytes"].as_u64().expect("bytes") as usize;
        let (w, h, rgb) = pixels(&b[at..at + bytes]);
        assert_eq!((w, h), (40, 75), "{image}");
        assert_eq!(image["rows"], 75, "{image}");
        let name = image["name"].as_str().expect("name");
        match stacked.last_mut() {
            Some((last, all)) if *last == name => all.extend_from_slice(&rgb),
            _ => stacked.push((name, rgb)),
        }
        at += bytes;
    }
    assert_eq!(at, b.len(), "the images fill the message");
    assert_eq!(
        header["png_bytes"].as_u64(),
        Some(
            images[0]["bytes"].as_u64().expect("bytes")
                + images[1]["bytes"].as_u64().expect("bytes")
        ),
        "png_bytes counts every band of the main image"
    );
    // The bands join: the reference is the abuffer's image of the view, row for row.
    let (_, reference) = &stacked[1];
    let dir = TempDir::new().expect("temp dir");
    let (_, source) = still_scene("spheres", &dir);
    let camera_toml = header["camera_toml"].as_str().expect("camera_toml");
    let (w, h, want) = pixels(&rendered(&source, camera_toml, &dir));
    assert_eq!((w, h), (40, 150));
    assert!(
        reference == &want,
        "the stacked reference is `strata render`'s image"
    );
    let c = &header["compare"];
    assert_eq!(c["method"], "abuffer");
    assert_eq!(c["stats"]["method"], "abuffer");
    assert!(
        c["bad_pixels"]["count"].as_u64().expect("count") > 0,
        "k = 1 loses layers: {c}"
    );
    assert!(c["mean_flip"].as_f64().expect("FLIP") > 0.0, "{c}");
}

#[test]
fn a_page_that_floods_questions_and_leaves_gives_its_seat_back() {
    let v = Viewer::start(&["--max-pages", "1"]);
    {
        let mut ws = v.socket();
        let hello = text(next(&mut ws).expect("hello"));
        ws.send(Message::text(
            json!({"type": "view", "id": 1, "width": 64, "height": 64, "camera": hello["camera"],
                   "method": "abuffer"})
            .to_string(),
        ))
        .expect("send");
        let _ = frame(next(&mut ws).expect("a frame"));
        // Questions until the server stops reading: its answers fill the socket, which this
        // page never reads.
        if let tungstenite::stream::MaybeTlsStream::Plain(s) = ws.get_ref() {
            s.set_write_timeout(Some(std::time::Duration::from_secs(2)))
                .expect("a write timeout");
        }
        for _ in 0..2_000_000 {
            if ws
                .send(Message::text(r#"{"type": "inspect", "x": 1, "y": 1}"#))
                .is_err()
            {
                break;
            }
        }
        // Gone without reading a single answer.
    }
    // The seat comes back once the work in hand is done; wait for it (no timing is asserted:
    // a seat that never comes back fails after a minute).
    for _ in 0..600 {
        let mut ws = v.socket();
        let first = text(next(&mut ws).expect("a first message"));
        if first["type"] == "hello" {
            return;
        }
        assert!(
            first["message"]
                .as_str()
                .expect("message")
                .contains("too many pages"),
            "{first}"
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    panic!("the page that left never gave its seat back");
}

#[test]
fn a_page_from_another_site_is_refused() {
    use tungstenite::client::IntoClientRequest;
    let v = Viewer::start(&[]);
    let mut request = format!("ws://{}/ws", v.addr)
        .into_client_request()
        .expect("request");
    request.headers_mut().insert(
        "Origin",
        "http://evil.example".parse().expect("header value"),
    );
    match tungstenite::connect(request) {
        Err(tungstenite::Error::Http(response)) => assert_eq!(response.status(), 403),
        other => panic!("a cross-site page was let in: {:?}", other.map(|_| ())),
    }
    // The viewer's own page is let in.
    let mut request = format!("ws://{}/ws", v.addr)
        .into_client_request()
        .expect("request");
    let own = format!("http://{}", v.addr);
    request
        .headers_mut()
        .insert("Origin", own.parse().expect("header value"));
    let (mut ws, _) = tungstenite::connect(request).expect("same origin");
    assert_eq!(text(next(&mut ws).expect("hello"))["type"], "hello");
}

/// The next frame whose header meets `wanted`; errors in between fail the test.
fn frame_where(ws: &mut Socket, wanted: impl Fn(&Value) -> bool) -> Value {
    for _ in 0..2000 {
        match next(ws).expect("a message") {
            m @ Message::Binary(_) => {
                let (header, _) = frame(m);
                if wanted(&header) {
                    return header;
                }
            }
            other => panic!("expected frames, got {other:?}"),
        }
    }
    panic!("no frame as wanted in 2000");
}

#[test]
fn an_mfr_page_grabs_and_drags_an_object_and_the_composite_stays_exact() {
    let v = Viewer::start_scene("mfr-cars", &["--mfr"]);
    let mut ws = v.socket();
    let hello = text(next(&mut ws).expect("hello"));
    assert!(
        hello["mfr"]["objects"].as_u64() > Some(100),
        "{}",
        hello["mfr"]
    );
    let settings = json!({"type": "mfr", "id": 1, "width": 160, "height": 90,
                          "camera": hello["camera"], "audit": true});
    ws.send(Message::text(settings.to_string())).expect("send");
    let settled = |h: &Value| h["mfr"]["sc_age_ms"] == json!(0.0);
    let first = frame_where(&mut ws, settled);
    assert_eq!(first["mfr"]["audit"]["bad_pixels"], 0, "{}", first["mfr"]);
    assert_eq!(first["camera"], hello["camera"]);

    // Hover the object the session offers, press, drag 4 pixels right.
    let handle = &first["mfr"]["handle_px"];
    let (x, y) = (
        handle[0].as_f64().expect("x"),
        handle[1].as_f64().expect("y"),
    );
    let pointer = |seq: u64, dx: f64, pressed: bool| {
        json!({"type": "pointer", "x": x + dx, "y": y, "pressed": pressed, "seq": seq}).to_string()
    };
    for (seq, dx, pressed) in [
        (1, 0.0, false),
        (2, 0.0, true),
        (3, 2.0, true),
        (4, 4.0, true),
    ] {
        ws.send(Message::text(pointer(seq, dx, pressed)))
            .expect("send");
    }
    let held = frame_where(&mut ws, |h| h["mfr"]["pointer_seq"] == 4 && settled(h));
    let m = &held["mfr"];
    assert_eq!(m["selected"], "steering wheel", "{m}");
    assert_eq!(m["fc_objects"], json!(["steering wheel"]), "{m}");
    assert!(m["moved"][0]["offset"][0].as_f64().expect("x") > 0.0, "{m}");
    assert_eq!(m["audit"]["bad_pixels"], 0, "{m}");

    // A view message is refused with the reason; the session goes on.
    let view = json!({"type": "view", "id": 2, "width": 8, "height": 8, "camera": hello["camera"],
                      "method": "abuffer"});
    ws.send(Message::text(view.to_string())).expect("send");
    loop {
        match next(&mut ws).expect("a message") {
            Message::Binary(_) => continue,
            m => {
                let e = text(m);
                assert!(
                    e["message"].as_str().expect("text").contains("--mfr"),
                    "{e}"
                );
                break;
            }
        }
    }
    ws.send(Message::text(pointer(5, 4.0, false)))
        .expect("send");
    let released = frame_where(&mut ws, |h| h["mfr"]["pointer_seq"] == 5 && settled(h));
    assert_eq!(released["mfr"]["selected"], Value::Null);
    assert_eq!(released["mfr"]["moved"], m["moved"]);
}

/// `strata node` serving some objects of a scene on `listen`.
fn node_at(scene: &str, objects: &str, listen: &str) -> Service {
    Service::start(&[
        "node",
        "--listen",
        listen,
        "--scene",
        scene,
        "--objects",
        objects,
    ])
}

/// Built-in scene `scene` as a file in `dir`, without its animation (a remote display poses
/// the scene at its frame number, which grows for as long as the page is open).
fn still_scene(scene: &str, dir: &TempDir) -> (String, String) {
    let source = Command::cargo_bin("strata")
        .expect("strata")
        .args(["scenes", "--print", scene])
        .output()
        .expect("runs");
    let source = String::from_utf8(source.stdout).expect("utf-8");
    let still = match source.find("[animation]") {
        None => source,
        Some(at) => {
            let rest = &source[at..];
            let end = rest.find("\n[").map_or(source.len(), |e| at + e + 1);
            format!("{}{}", &source[..at], &source[end..])
        }
    };
    let path = dir.path().join(format!("{scene}.toml"));
    std::fs::write(&path, &still).expect("write");
    (path.to_str().expect("utf-8").to_owned(), still)
}

/// The PNG `strata render` makes of the scene file `source` through the view a frame reports.
fn rendered(source: &str, camera_toml: &str, dir: &TempDir) -> Vec<u8> {
    let objects = &source[source.find("[[objects]]").expect("objects")..];
    let background = source
        .lines()
        .find(|l| l.starts_with("background"))
        .expect("a background");
    let (size, camera) = camera_toml.split_once("[camera]").expect("a camera table");
    let file = dir.path().join("view.toml");
    let out = dir.path().join("render.png");
    std::fs::write(
        &file,
        format!("{size}{background}\n\n[camera]{camera}\n{objects}"),
    )
    .expect("write");
    Command::cargo_bin("strata")
        .expect("strata")
        .args(["render", file.to_str().expect("utf-8"), "-j", "1"])
        .arg("--out")
        .arg(&out)
        .assert()
        .success();
    std::fs::read(&out).expect("render output")
}

/// The next frame message whose header meets `wanted`, with its PNG; errors in between fail.
fn frame_and_png_where(ws: &mut Socket, wanted: impl Fn(&Value) -> bool) -> (Value, Vec<u8>) {
    for _ in 0..2000 {
        match next(ws).expect("a message") {
            m @ Message::Binary(_) => {
                let (header, png) = frame(m);
                if wanted(&header) {
                    return (header, png);
                }
            }
            other => panic!("expected frames, got {other:?}"),
        }
    }
    panic!("no frame as wanted in 2000");
}

#[test]
fn a_remote_page_shows_its_nodes_through_its_camera_and_outlives_a_dead_node() {
    let dir = TempDir::new().expect("temp dir");
    let (scene, source) = still_scene("mixed", &dir);
    let a = node_at(&scene, "opaque cube,glass slab", "127.0.0.1:0");
    let b = node_at(&scene, "1,2,4", "127.0.0.1:0");
    let b_addr = b.addr.clone();
    let nodes = format!("{},{}", a.addr, b.addr);
    // Difference transfer: the nodes' objects overlap on screen, so every camera move needs
    // the fixup round, which must render through the same camera as the frame.
    let v = Viewer::start_scene(
        &scene,
        &[
            "--nodes",
            &nodes,
            "--transfer",
            "difference",
            "--timeout",
            "10",
        ],
    );
    let mut ws = v.socket();
    let hello = text(next(&mut ws).expect("hello"));
    assert_eq!(hello["remote"]["nodes"], json!([a.addr, b.addr]));
    assert_eq!(hello["remote"]["transfer"], "difference");
    assert_eq!(hello["remote"]["codec"], "deep-huff");

    let settings = |id: u64, eye: [f32; 3], width: u32| {
        let camera = json!({"eye": eye, "target": [0, 0, 0], "up": [0, 1, 0],
                            "fovy_deg": 45, "near": 0.01, "far": 100});
        Message::text(
            json!({"type": "remote", "id": id, "width": width, "height": 64, "camera": camera,
                   "max_fps": 60})
            .to_string(),
        )
    };
    let mut shown = Vec::new();
    for (id, eye) in [(1, [0.35, 0.45, 1.7]), (2, [-1.2, 0.3, 1.1])] {
        ws.send(settings(id, eye, 96)).expect("send");
        let (header, png) = frame_and_png_where(&mut ws, |h| h["id"] == id);
        let r = &header["remote"];
        assert_eq!(r["nodes"].as_array().map(Vec::len), Some(2), "{r}");
        for n in r["nodes"].as_array().expect("nodes") {
            assert_eq!(n["status"], "ok", "{r}");
        }
        assert_eq!(header["camera"]["eye"], json!(eye));
        let (w, h, got) = pixels(&png);
        assert_eq!((w, h), (96, 64));
        // Merged from two nodes, it is what one machine renders of the whole scene.
        let camera_toml = header["camera_toml"].as_str().expect("camera_toml");
        let (_, _, expected) = pixels(&rendered(&source, camera_toml, &dir));
        assert!(got == expected, "frame {id} differs from strata render's");
        shown.push(got);
    }
    assert!(shown[0] != shown[1], "the camera moved the image");

    // A pixel of the cube, behind the glass: fragments of both nodes' objects.
    ws.send(Message::text(
        json!({"type": "inspect", "x": 48, "y": 32, "frame": 2}).to_string(),
    ))
    .expect("send");
    let pixel = loop {
        match next(&mut ws).expect("a message") {
            Message::Binary(_) => continue,
            m => break text(m),
        }
    };
    assert_eq!(pixel["type"], "pixel", "{pixel}");
    assert!(
        pixel["method"]
            .as_str()
            .is_some_and(|m| m.contains("difference from 2 node(s)")),
        "{pixel}"
    );
    let fragments = pixel["fragments"].as_array().expect("fragments");
    assert!(!fragments.is_empty(), "{pixel}");
    let depths: Vec<f64> = fragments
        .iter()
        .filter_map(|f| f["depth"].as_f64())
        .collect();
    assert!(
        depths.windows(2).all(|d| d[0] <= d[1]),
        "front to back: {pixel}"
    );
    // Each fragment names the node that rendered it.
    for f in fragments {
        let a_renders = matches!(f["name"].as_str(), Some("opaque cube" | "glass slab"));
        let node = if a_renders { &a.addr } else { &b_addr };
        assert_eq!(f["client"], json!(node), "{pixel}");
    }

    // Settings it refuses leave the display running.
    ws.send(settings(3, [0.35, 0.45, 1.7], 5000)).expect("send");
    let refusal = loop {
        match next(&mut ws).expect("a message") {
            Message::Binary(_) => continue,
            m => break text(m),
        }
    };
    assert!(
        refusal["message"]
            .as_str()
            .is_some_and(|m| m.contains("width 5000")),
        "{refusal}"
    );

    // A node dies: the page goes on with its last frame held, and says so.
    drop(b);
    let (header, png) = frame_and_png_where(&mut ws, |h| {
        h["remote"]["nodes"][1]["status"] == "held"
            && h["remote"]["incidents"]
                .as_array()
                .is_some_and(|i| !i.is_empty())
    });
    let r = &header["remote"];
    assert_eq!(r["nodes"][0]["status"], "ok", "{r}");
    let dead = json!(b_addr);
    let incidents = r["incidents"].as_array().expect("incidents");
    assert!(incidents.iter().any(|i| i["node"] == dead), "{r}");
    assert!(r["incident_count"].as_u64() >= Some(1), "{r}");
    // Held, the still scene looks as it did.
    assert!(
        pixels(&png).2 == shown[1],
        "a held node keeps its part of the image"
    );

    // A new size restarts the display, the dead node still left out.
    ws.send(settings(4, [0.35, 0.45, 1.7], 80)).expect("send");
    let (header, png) = frame_and_png_where(&mut ws, |h| h["id"] == 4);
    assert_eq!(pixels(&png).0, 80);
    let r = &header["remote"];
    assert_eq!(r["nodes"][0]["status"], "ok", "{r}");
    assert!(
        r["nodes"][1]["status"] == "held" || r["nodes"][1]["status"] == "dropped",
        "{r}"
    );

    // The node comes back on its address: it rejoins, and the frame is whole again.
    let _b = node_at(&scene, "1,2,4", &b_addr);
    let (header, png) = frame_and_png_where(&mut ws, |h| {
        h["remote"]["nodes"]
            .as_array()
            .is_some_and(|n| n.iter().all(|n| n["status"] == "ok"))
    });
    let camera_toml = header["camera_toml"].as_str().expect("camera_toml");
    let (_, _, expected) = pixels(&rendered(&source, camera_toml, &dir));
    assert!(pixels(&png).2 == expected, "back, the frame is exact again");

    // The page switches the transfer: the display restarts with it, still exact.
    let camera = json!({"eye": [0.35, 0.45, 1.7], "target": [0, 0, 0], "up": [0, 1, 0],
                        "fovy_deg": 45, "near": 0.01, "far": 100});
    let switch = json!({"type": "remote", "id": 5, "width": 80, "height": 64, "camera": camera,
                        "max_fps": 60, "transfer": "depth-limited", "layers": 64});
    ws.send(Message::text(switch.to_string())).expect("send");
    let (header, png) = frame_and_png_where(&mut ws, |h| {
        h["id"] == 5
            && h["remote"]["nodes"]
                .as_array()
                .is_some_and(|n| n.iter().all(|n| n["status"] == "ok"))
    });
    assert_eq!(header["remote"]["transfer"], "depth-limited --layers 64");
    let camera_toml = header["camera_toml"].as_str().expect("camera_toml");
    let (_, _, expected) = pixels(&rendered(&source, camera_toml, &dir));
    assert!(
        pixels(&png).2 == expected,
        "64 layers keep every fragment here"
    );
}

#[test]
fn remote_options_need_nodes_and_nodes_need_a_remote_page() {
    refused(
        &["view", "mixed", "--transfer", "difference"],
        "apply to the remote mode only: add --nodes",
    );
    refused(&["view", "mixed", "--nodes", "nowhere"], "is not HOST:PORT");
    refused(
        &["view", "mixed", "--nodes", "127.0.0.1:9", "--mfr"],
        "cannot be used with",
    );
    refused(
        &[
            "view",
            "mixed",
            "--nodes",
            "127.0.0.1:9",
            "--tolerance",
            "3",
        ],
        "--tolerance applies to --transfer difference and reprojection only",
    );
}

#[test]
fn a_remote_page_asking_more_than_eight_questions_at_once_is_told_to_wait() {
    let dir = TempDir::new().expect("temp dir");
    let (scene, _) = still_scene("mixed", &dir);
    let node = Service::start(&["node", "--listen", "127.0.0.1:0", "--scene", &scene]);
    let v = Viewer::start_scene(&scene, &["--nodes", &node.addr, "--timeout", "10"]);
    let mut ws = v.socket();
    let _hello = text(next(&mut ws).expect("hello"));
    // One frame a second: questions are taken up with the next frame, so a burst stays queued.
    let camera = json!({"eye": [0.35, 0.45, 1.7], "target": [0, 0, 0], "up": [0, 1, 0],
                        "fovy_deg": 45, "near": 0.01, "far": 100});
    ws.send(Message::text(
        json!({"type": "remote", "id": 1, "width": 64, "height": 48, "camera": camera,
               "max_fps": 1})
        .to_string(),
    ))
    .expect("send");
    let _ = frame_and_png_where(&mut ws, |h| h["id"] == 1);
    const ASKED: usize = 30;
    for _ in 0..ASKED {
        ws.send(Message::text(
            json!({"type": "inspect", "x": 32, "y": 24}).to_string(),
        ))
        .expect("send");
    }
    // Every question gets an answer or the error that says to wait; none is dropped silently.
    // Queued questions are answered with the next frame, so a few frames are plenty: a
    // question still unanswered after ten has been lost.
    let (mut answers, mut refusals, mut frames) = (0, 0, 0);
    while answers + refusals < ASKED {
        match next(&mut ws).expect("a message") {
            Message::Binary(_) => {
                frames += 1;
                assert!(
                    frames <= 10,
                    "{} of {ASKED} questions unanswered after {frames} frames",
                    ASKED - answers - refusals
                );
            }
            m => {
                let m = text(m);
                match m["type"].as_str() {
                    Some("pixel") => answers += 1,
                    Some("error") => {
                        assert!(
                            m["message"]
                                .as_str()
                                .is_some_and(|t| t.contains("too many questions at once")),
                            "{m}"
                        );
                        refusals += 1;
                    }
                    _ => panic!("unexpected {m}"),
                }
            }
        }
    }
    // At most eight wait for a frame (a frame could, rarely, fall inside the burst and take
    // some: then more are answered, but a burst of 30 still overflows the queue).
    assert!(refusals >= 1, "{answers} answered, {refusals} refused");
    assert!(answers >= 8, "{answers} answered, {refusals} refused");
}
