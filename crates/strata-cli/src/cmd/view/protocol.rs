//! The viewer's messages, and the checks that turn a page's request into a render job.
//!
//! One WebSocket per page. Text messages are JSON objects with a `type`:
//!
//! ```text
//! page → server   {"type": "view", "id": 7, "width": 800, "height": 450, "frame": 0,
//!                  "camera": {"eye": [x, y, z], "target": […], "up": […],
//!                             "fovy_deg": 45, "near": 0.01, "far": 100},
//!                  "method": "kbuffer", "options": {"k": "2", "tail-blend": "true"}}
//!                 {"type": "inspect", "x": 120, "y": 40, "frame": 7}   the fragments of one
//!                                                 pixel of frame 7, if it is still the latest
//!                 {"type": "save_deep"}          the latest frame as a deep OpenEXR file: a
//!                                                binary message like a frame's, header type
//!                                                "deep", one image named "deep" (the EXR)
//!   with --mfr    {"type": "mfr", "id": 7, "width", "height", "camera": {…},
//!    instead of    "composition": "deep", "migration": "predictive", "fc_hz": 30,
//!    "view"        "sc_interval_ms": 0, "audit": false}   the multi-frame-rate session's settings
//!                 {"type": "pointer", "x": 120.5, "y": 40, "pressed": true, "seq": 9}
//!                                                the pointer over pixel (x, y) of the frame shown
//!   with --nodes  {"type": "remote", "id": 7, "width", "height", "camera": {…}, "max_fps": 30}
//!    instead of                                  the display's settings: every frame requested
//!    "view"                                      from then on is rendered through this camera
//! server → page   {"type": "hello", …}        once, on connecting: the scene, its camera and
//!                                             size, the methods and their options (see `hello`)
//!                 {"type": "error", "id": 7, "message": "…"}   a request refused or failed
//!                 {"type": "pixel", "frame": 7, "x", "y", "fragments": [{"depth", "rgba",
//!                  "object", "name"}, …]}     front to back, as the frame's DeepFrame holds them
//! ```
//!
//! A view may carry `"compare": {"method": "abuffer", "options": {…}, "flip": false}`: the
//! reference is rendered for the same view and compared with the method's image (RMSE, bad
//! pixels, and FLIP's mean and heat map when `flip` is set).
//!
//! A frame is one binary message: a `u32` little-endian header length, the header (JSON:
//! `{"type": "frame", "id", "stats", "camera_toml", "render_ms", "encode_ms", "images", …}`,
//! where `stats` is exactly what `strata render --stats` writes) and the images, PNGs one after
//! the other in the order and with the byte lengths `images` lists (`[{"name": "main", "bytes":
//! n, "rows": r}, …]`; with a comparison also `reference`, `bad` and, with FLIP, `flip`). The
//! header and the images travel together, so a page never pairs an image with another frame's
//! numbers.
//!
//! An image of at least twice [`MIN_BAND_ROWS`] rows, encoded by a pool of several threads,
//! comes as several PNGs ([`bands`]), one a band of `rows` full-width rows, consecutive entries
//! of one name stacked top to bottom: the server encodes the bands on all its threads at once
//! (one PNG is a single deflate stream, so one thread), and the page decodes them at once. A
//! `deep` message's entry (the EXR) has no `rows`.
//!
//! Every field of a request is checked here, with the rules the command line and the scene
//! file use: the camera by [`Camera::check`], the size against [`MAX_SIDE`], the frame against
//! the scene's animation, and the method's options by [`crate::options::configure`], so the page
//! refuses what `strata render` refuses, with the same words.

use std::collections::BTreeMap;

use anyhow::{Context, Result, anyhow, bail};
use serde::Deserialize;
use serde_json::{Value, json};
use strata_scene::{Camera, Scene};
use strata_stores::MethodOptions;

/// The largest side of a frame the viewer renders, in pixels.
pub(crate) const MAX_SIDE: u32 = 4096;

/// The most a store with a fixed number of fragments per pixel (`kbuffer`'s `k`,
/// `abuffer-array`'s `array-size`) may reserve for one page, in bytes: more is refused before
/// anything is allocated, so one page cannot take the server's memory.
pub(crate) const MAX_FIXED_STORE_BYTES: u64 = 2 << 30;

/// A camera as a page sends it: scene-file terms.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CameraMessage {
    eye: [f64; 3],
    target: [f64; 3],
    up: [f64; 3],
    fovy_deg: f64,
    near: f64,
    far: f64,
}

/// A view request as a page sends it.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct ViewMessage {
    /// The page's number for the request; frames and errors carry it back.
    id: u64,
    width: u32,
    height: u32,
    #[serde(default)]
    frame: u32,
    camera: CameraMessage,
    method: String,
    /// Option name → value, as `compare --methods` specs write them; a flag's value is
    /// `"true"` or `"false"`.
    #[serde(default)]
    options: BTreeMap<String, String>,
    /// Also render a reference method for the same view and compare the two.
    #[serde(default)]
    compare: Option<CompareMessage>,
}

/// The reference a view is compared with.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CompareMessage {
    method: String,
    #[serde(default)]
    options: BTreeMap<String, String>,
    /// Also compute FLIP (its mean and heat map): a few times slower than the render.
    #[serde(default)]
    flip: bool,
}

/// The settings of a multi-frame-rate page (`strata view --mfr`).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct MfrMessage {
    id: u64,
    width: u32,
    height: u32,
    /// The camera: its eye, target and up move the view; the projection is the scene's.
    camera: CameraMessage,
    #[serde(default = "default_composition")]
    composition: String,
    #[serde(default = "default_migration")]
    migration: String,
    /// The fast client's most frames a second.
    #[serde(default = "default_fc_hz")]
    fc_hz: f64,
    /// The slow client's least time between frames (0: as fast as it can).
    #[serde(default)]
    sc_interval_ms: f64,
    /// Also render the whole scene at once and audit each frame against it.
    #[serde(default)]
    audit: bool,
}

fn default_composition() -> String {
    "deep".into()
}

fn default_migration() -> String {
    "predictive".into()
}

fn default_fc_hz() -> f64 {
    30.0
}

/// The settings of a remote page (`strata view --nodes`).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RemoteMessage {
    id: u64,
    width: u32,
    height: u32,
    camera: CameraMessage,
    /// The most frames a second the display composes (it asks the nodes no faster).
    #[serde(default = "default_fc_hz")]
    max_fps: f64,
    /// The transfer method, as `--transfer` names it (absent: the command line's), with its
    /// options as `--layers`, `--opacity-threshold` and `--tolerance` take them.
    #[serde(default)]
    transfer: Option<String>,
    #[serde(default)]
    layers: Option<u32>,
    #[serde(default)]
    opacity_threshold: Option<f32>,
    #[serde(default)]
    tolerance: Option<u8>,
}

/// What a page may send.
#[derive(Clone, Debug, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub(crate) enum PageMessage {
    /// Render this view; it replaces any view not yet rendered.
    View(Box<ViewMessage>),
    /// The multi-frame-rate session's settings; they replace the previous ones.
    Mfr(Box<MfrMessage>),
    /// The remote display's settings; they replace the previous ones.
    Remote(Box<RemoteMessage>),
    /// The pointer over a pixel of the frame shown, pressed or not (multi-frame-rate pages).
    Pointer {
        x: f32,
        y: f32,
        pressed: bool,
        /// The page's number for the event; frames say the newest they show.
        #[serde(default)]
        seq: Option<u64>,
    },
    /// List the fragments of one pixel of the latest frame; with `frame`, only if the latest
    /// frame is still the one of that request id.
    Inspect {
        x: u32,
        y: u32,
        #[serde(default)]
        frame: Option<u64>,
    },
    /// Send the latest frame's DeepFrame as a deep OpenEXR file.
    SaveDeep,
}

/// A checked message.
#[derive(Clone, Debug)]
pub(crate) enum Request {
    /// Render this.
    View(Box<Job>),
    /// Run the multi-frame-rate session with these settings.
    Mfr(Box<MfrJob>),
    /// Display the render nodes' frames with these settings.
    Remote(Box<RemoteJob>),
    /// The pointer moved or its button changed.
    Pointer(PointerInput),
    /// A question about the latest frame, answered between frames.
    About(Probe),
}

/// A question about the latest frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Probe {
    /// The fragments of pixel `(x, y)` (checked against the frame's size when answered) of the
    /// frame of that request id, if one is given.
    Pixel(u32, u32, Option<u64>),
    /// The whole DeepFrame as a deep OpenEXR file.
    Deep,
}

/// A method with checked options.
#[derive(Clone, Debug)]
pub(crate) struct MethodChoice {
    pub(crate) method: String,
    pub(crate) options: MethodOptions,
    /// The method and its settings in one string: a store is rebuilt only when this changes.
    pub(crate) key: String,
}

/// A checked request: everything a render needs.
#[derive(Clone, Debug)]
pub(crate) struct Job {
    /// The page's request number.
    pub(crate) id: u64,
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) frame: u32,
    pub(crate) camera: Camera,
    pub(crate) main: MethodChoice,
    /// The reference to compare with, and whether to compute FLIP.
    pub(crate) compare: Option<(MethodChoice, bool)>,
}

/// Checked multi-frame-rate settings.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct MfrJob {
    pub(crate) id: u64,
    pub(crate) width: u32,
    pub(crate) height: u32,
    /// The scene's camera moved to the page's eye, target and up.
    pub(crate) camera: Camera,
    pub(crate) composition: strata_mfr::Composition,
    pub(crate) migration: strata_mfr::simulate::Migration,
    pub(crate) fc_hz: f64,
    pub(crate) sc_interval_ms: f64,
    pub(crate) audit: bool,
}

/// Checked remote-display settings.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct RemoteJob {
    pub(crate) id: u64,
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) camera: Camera,
    pub(crate) max_fps: f64,
    /// The transfer method and its tolerance, if the page chose one.
    pub(crate) transfer: Option<(strata_remote::Transfer, u8)>,
}

/// What a viewer serves, and so which messages it takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Mode {
    /// Views rendered with a chosen method (`view`).
    Views,
    /// The multi-frame-rate session (`mfr`, `pointer`).
    Mfr,
    /// A display of render nodes (`remote`).
    Remote,
}

impl Mode {
    /// How to start a viewer that takes what this one refuses.
    fn command(self) -> &'static str {
        match self {
            Mode::Views => "`strata view SCENE`",
            Mode::Mfr => "`strata view SCENE --mfr`",
            Mode::Remote => "`strata view SCENE --nodes HOST:PORT,…`",
        }
    }
}

/// The largest side of a remote frame: the display keeps a copy of every node's fragments.
pub(crate) const MAX_REMOTE_SIDE: u32 = 2048;

/// A pointer event of a multi-frame-rate page.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PointerInput {
    pub(crate) x: f32,
    pub(crate) y: f32,
    pub(crate) pressed: bool,
    pub(crate) seq: Option<u64>,
}

/// The largest side of a multi-frame-rate frame: each page holds the fast client's, the slow
/// client's and (audited) the single renderer's fragments, and the buffers between them — about
/// 0.6 KB a pixel on `mfr-cars`, so 2.5 GB a page at 2048².
pub(crate) const MAX_MFR_SIDE: u32 = 2048;

/// The highest fast-client rate a page may ask for (frames a second).
pub(crate) const MAX_FC_HZ: f64 = 240.0;

/// The longest a page may hold the slow client between frames (ms).
pub(crate) const MAX_SC_INTERVAL_MS: f64 = 10_000.0;

/// The request number of a text message, if it has one, so an error about it can carry it.
pub(crate) fn request_id(text: &str) -> Option<u64> {
    serde_json::from_str::<Value>(text)
        .ok()?
        .get("id")?
        .as_u64()
}

/// Parses and checks one text message from a page; `mode` is what the server serves (each
/// mode takes its own settings message: `view`, `mfr` and `pointer`, or `remote`).
pub(crate) fn parse(text: &str, scene: &Scene, mode: Mode) -> Result<Request> {
    let message: PageMessage =
        serde_json::from_str(text).map_err(|e| anyhow!("malformed message: {e}"))?;
    let belongs = match &message {
        PageMessage::View(_) => Some(Mode::Views),
        PageMessage::Mfr(_) | PageMessage::Pointer { .. } => Some(Mode::Mfr),
        PageMessage::Remote(_) => Some(Mode::Remote),
        PageMessage::Inspect { .. } | PageMessage::SaveDeep => None,
    };
    if let Some(wanted) = belongs
        && wanted != mode
    {
        let (serves, takes) = match mode {
            Mode::Views => ("renders views", "\"view\" requests"),
            Mode::Mfr => (
                "runs the multi-frame-rate session",
                "\"mfr\" settings and \"pointer\" events",
            ),
            Mode::Remote => ("displays render nodes", "\"remote\" settings"),
        };
        bail!(
            "this viewer {serves} ({}): send {takes}; start it with {} for that message",
            mode.command(),
            wanted.command()
        );
    }
    match message {
        PageMessage::View(m) => view(*m, scene).map(|job| Request::View(Box::new(job))),
        PageMessage::Mfr(m) => mfr_settings(*m, scene).map(|job| Request::Mfr(Box::new(job))),
        PageMessage::Remote(m) => remote_settings(*m).map(|job| Request::Remote(Box::new(job))),
        PageMessage::Pointer { x, y, pressed, seq } => {
            if !(x.is_finite() && y.is_finite() && x.abs() <= 1e6 && y.abs() <= 1e6) {
                bail!("pointer at ({x}, {y}): expected pixel coordinates");
            }
            Ok(Request::Pointer(PointerInput { x, y, pressed, seq }))
        }
        PageMessage::Inspect { x, y, frame } => Ok(Request::About(Probe::Pixel(x, y, frame))),
        PageMessage::SaveDeep => Ok(Request::About(Probe::Deep)),
    }
}

/// The frame size of a request, checked against [`MAX_SIDE`].
fn size(width: u32, height: u32) -> Result<()> {
    for (name, side) in [("width", width), ("height", height)] {
        if !(1..=MAX_SIDE).contains(&side) {
            bail!("{name} {side} is outside 1..={MAX_SIDE} pixels");
        }
    }
    Ok(())
}

/// Refuses a frame side above a mode's own limit `max`, saying what `frames` keep (`why`).
fn at_most((width, height): (u32, u32), max: u32, frames: &str, why: &str) -> Result<()> {
    for (name, side) in [("width", width), ("height", height)] {
        if side > max {
            bail!(
                "{name} {side}: {frames} are at most {max} pixels a side ({why}); use ?size=WxH \
                 in the address"
            );
        }
    }
    Ok(())
}

/// A page's camera, checked as a scene file's is.
fn camera(c: &CameraMessage) -> Result<Camera> {
    let v = |a: [f64; 3]| glam::Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32);
    let camera = Camera {
        eye: v(c.eye),
        target: v(c.target),
        up: v(c.up),
        fovy_deg: c.fovy_deg as f32,
        near: c.near as f32,
        far: c.far as f32,
    };
    camera.check()?;
    Ok(camera)
}

/// Checks multi-frame-rate settings.
fn mfr_settings(m: MfrMessage, scene: &Scene) -> Result<MfrJob> {
    use strata_mfr::Composition;
    use strata_mfr::simulate::Migration;
    size(m.width, m.height)?;
    at_most(
        (m.width, m.height),
        MAX_MFR_SIDE,
        "multi-frame-rate frames",
        "both clients keep every fragment",
    )?;
    let given = camera(&m.camera)?;
    // The clients project with the scene's camera; the page moves its eye, target and up.
    let camera = Camera {
        eye: given.eye,
        target: given.target,
        up: given.up,
        ..scene.camera
    };
    camera.check()?;
    let composition = match m.composition.as_str() {
        "deep" => Composition::Deep,
        "digital" => Composition::Digital,
        "optical" => Composition::Optical,
        other => bail!("composition '{other}': expected deep, digital or optical"),
    };
    let migration = match m.migration.as_str() {
        "predictive" => Migration::Predictive,
        "naive" => Migration::Naive,
        other => bail!("migration '{other}': expected predictive or naive"),
    };
    if !(m.fc_hz.is_finite() && m.fc_hz >= 1.0 && m.fc_hz <= MAX_FC_HZ) {
        bail!(
            "fc_hz {} is outside 1..={MAX_FC_HZ} frames a second",
            m.fc_hz
        );
    }
    if !(m.sc_interval_ms.is_finite() && (0.0..=MAX_SC_INTERVAL_MS).contains(&m.sc_interval_ms)) {
        bail!(
            "sc_interval_ms {} is outside 0..={MAX_SC_INTERVAL_MS} ms",
            m.sc_interval_ms
        );
    }
    Ok(MfrJob {
        id: m.id,
        width: m.width,
        height: m.height,
        camera,
        composition,
        migration,
        fc_hz: m.fc_hz,
        sc_interval_ms: m.sc_interval_ms,
        audit: m.audit,
    })
}

/// Checks remote-display settings.
fn remote_settings(m: RemoteMessage) -> Result<RemoteJob> {
    size(m.width, m.height)?;
    at_most(
        (m.width, m.height),
        MAX_REMOTE_SIDE,
        "remote frames",
        "the display keeps every node's fragments",
    )?;
    let camera = camera(&m.camera)?;
    if !(m.max_fps.is_finite() && m.max_fps >= 1.0 && m.max_fps <= MAX_FC_HZ) {
        bail!(
            "max_fps {} is outside 1..={MAX_FC_HZ} frames a second",
            m.max_fps
        );
    }
    let transfer = match &m.transfer {
        Some(name) => Some(
            crate::cmd::display::choose_transfer(name, m.layers, m.opacity_threshold, m.tolerance)
                .context("transfer")?,
        ),
        None if m.layers.is_some() || m.opacity_threshold.is_some() || m.tolerance.is_some() => {
            bail!("layers, opacity_threshold and tolerance go with a transfer")
        }
        None => None,
    };
    Ok(RemoteJob {
        id: m.id,
        width: m.width,
        height: m.height,
        camera,
        max_fps: m.max_fps,
        transfer,
    })
}

/// Checks a view request.
fn view(m: ViewMessage, scene: &Scene) -> Result<Job> {
    let ViewMessage {
        id,
        width,
        height,
        frame,
        camera,
        method,
        options,
        compare,
    } = m;
    size(width, height)?;
    scene.check_frame(frame)?;
    let camera = self::camera(&camera)?;
    let main = choice(method, &options).context("method")?;
    check_memory(&main, width, height).context("method")?;
    let compare = match compare {
        None => None,
        Some(c) => {
            let reference = choice(c.method, &c.options).context("reference")?;
            check_memory(&reference, width, height).context("reference")?;
            Some((reference, c.flip))
        }
    };
    Ok(Job {
        id,
        width,
        height,
        frame,
        camera,
        main,
        compare,
    })
}

/// Refuses a store whose fixed per-pixel arrays would exceed [`MAX_FIXED_STORE_BYTES`] (at 16
/// bytes a fragment slot, what the fixed stores keep with their counts).
fn check_memory(choice: &MethodChoice, width: u32, height: u32) -> Result<()> {
    let (option, per_pixel) = match choice.method.as_str() {
        "kbuffer" => ("k", choice.options.k),
        "abuffer-array" => ("array-size", choice.options.array_size),
        _ => return Ok(()),
    };
    let bytes = u64::from(width) * u64::from(height) * u64::from(per_pixel) * 16;
    if bytes > MAX_FIXED_STORE_BYTES {
        bail!(
            "{} with {option} = {per_pixel} at {width}x{height} would reserve about {:.1} GiB, \
             more than the {} GiB a page's store may; lower {option} or the frame size \
             (?size=WxH in the address)",
            choice.method,
            bytes as f64 / f64::from(1u32 << 30),
            MAX_FIXED_STORE_BYTES >> 30
        );
    }
    Ok(())
}

/// Checks a method and its options.
pub(crate) fn choice(method: String, options: &BTreeMap<String, String>) -> Result<MethodChoice> {
    strata_stores::find(&method)?;
    if options.contains_key("weights") {
        bail!(
            "weights: the viewer uses the weights built into strata; a weights file is read by \
             `strata render --weights`"
        );
    }
    let settings = options.iter().map(|(k, v)| (k.as_str(), Some(v.as_str())));
    let checked = crate::options::configure(&method, &MethodOptions::default(), settings)?;
    let key = std::iter::once(method.clone())
        .chain(options.iter().map(|(k, v)| format!("{k}={v}")))
        .collect::<Vec<_>>()
        .join(":");
    Ok(MethodChoice {
        method,
        options: checked,
        key,
    })
}

/// A camera in scene-file terms, as a page shows and sends it.
pub(crate) fn camera_json(c: &Camera) -> Value {
    json!({
        "eye": c.eye.to_array(),
        "target": c.target.to_array(),
        "up": c.up.to_array(),
        "fovy_deg": c.fovy_deg,
        "near": c.near,
        "far": c.far,
    })
}

/// The size and `[camera]` table of a view, as lines to paste into a scene file. Numbers are
/// written in the shortest form that reads back to the same `f32`, so the pasted scene renders
/// the very same image.
pub(crate) fn view_toml(c: &Camera, width: u32, height: u32) -> String {
    let v = |a: glam::Vec3| format!("[{}, {}, {}]", a.x, a.y, a.z);
    format!(
        "width = {width}\nheight = {height}\n\n[camera]\neye = {}\ntarget = {}\nup = {}\n\
         fovy_deg = {}\nnear = {}\nfar = {}\n",
        v(c.eye),
        v(c.target),
        v(c.up),
        c.fovy_deg,
        c.near,
        c.far
    )
}

/// An error message for a page.
pub(crate) fn error_json(id: Option<u64>, message: &str) -> String {
    json!({"type": "error", "id": id, "message": message}).to_string()
}

/// Fewest rows in a band of an image sent in bands (see the module docs): a small image is one
/// PNG, since a band's PNG costs its header and a fresh deflate dictionary.
pub(crate) const MIN_BAND_ROWS: u32 = 64;

/// One part of a binary message: a PNG of `rows` rows of the image `name` (a band, or the
/// whole image), or a file (`rows: None`).
#[derive(Debug, PartialEq)]
pub(crate) struct Part<'a> {
    pub(crate) name: &'a str,
    pub(crate) rows: Option<u32>,
    pub(crate) bytes: Vec<u8>,
}

impl Part<'_> {
    /// The bytes of the image `name` in `parts`, all its bands together.
    pub(crate) fn image_bytes(parts: &[Part<'_>], name: &str) -> usize {
        parts
            .iter()
            .filter(|p| p.name == name)
            .map(|p| p.bytes.len())
            .sum()
    }
}

/// The bands an image of `height` rows is sent in: as many as the threads encoding them, each
/// of at least [`MIN_BAND_ROWS`] rows (one band for a smaller image), as even as can be.
pub(crate) fn bands(height: u32, threads: usize) -> Vec<std::ops::Range<u32>> {
    let n = (height / MIN_BAND_ROWS).clamp(1, threads.max(1) as u32);
    (0..n)
        .map(|i| height * i / n..height * (i + 1) / n)
        .collect()
}

/// The named images of a frame as PNGs, in order, each in [`bands`] encoded in parallel on the
/// current rayon pool.
pub(crate) fn encode_pngs<'a, I>(images: &[(&'a str, I)]) -> Result<Vec<Part<'a>>>
where
    I: std::borrow::Borrow<strata_core::Rgb8Image> + Sync,
{
    use rayon::prelude::*;
    let threads = rayon::current_num_threads();
    let jobs: Vec<(&'a str, &strata_core::Rgb8Image, std::ops::Range<u32>)> = images
        .iter()
        .flat_map(|(name, image)| {
            let image = image.borrow();
            bands(image.height(), threads)
                .into_iter()
                .map(move |rows| (*name, image, rows))
        })
        .collect();
    jobs.into_par_iter()
        .map(|(name, image, rows)| {
            let mut bytes = Vec::new();
            image
                .encode_png_rows(rows.clone(), &mut bytes)
                .with_context(|| format!("cannot encode the {name} image as PNG"))?;
            Ok(Part {
                name,
                rows: Some(rows.end - rows.start),
                bytes,
            })
        })
        .collect()
}

/// A frame message: header length, header with the list of the parts (`images`) added, the
/// parts' bytes.
pub(crate) fn frame_message(mut header: Value, parts: &[Part<'_>]) -> Vec<u8> {
    header["images"] = parts
        .iter()
        .map(|p| match p.rows {
            Some(rows) => json!({"name": p.name, "bytes": p.bytes.len(), "rows": rows}),
            None => json!({"name": p.name, "bytes": p.bytes.len()}),
        })
        .collect();
    let header = header.to_string();
    let size = parts.iter().map(|p| p.bytes.len()).sum::<usize>();
    let mut out = Vec::with_capacity(4 + header.len() + size);
    out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for p in parts {
        out.extend_from_slice(&p.bytes);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> Scene {
        strata_scene::open_scene("spheres", &strata_scene::SearchPath::default())
            .expect("built-in scene")
    }

    fn request(patch: impl FnOnce(&mut Value)) -> String {
        let mut v = json!({
            "type": "view", "id": 3, "width": 64, "height": 48,
            "camera": {"eye": [0, 0, 2], "target": [0, 0, 0], "up": [0, 1, 0],
                       "fovy_deg": 45, "near": 0.01, "far": 100},
            "method": "kbuffer", "options": {"k": "2"}
        });
        patch(&mut v);
        v.to_string()
    }

    fn refused(text: &str) -> String {
        match parse(text, &scene(), Mode::Views) {
            Ok(request) => panic!("accepted {text}: {request:?}"),
            Err(e) => format!("{e:#}"),
        }
    }

    #[test]
    fn a_good_request_becomes_a_job() {
        let Ok(Request::View(job)) = parse(&request(|_| {}), &scene(), Mode::Views) else {
            panic!("a valid view request");
        };
        assert_eq!((job.id, job.width, job.height, job.frame), (3, 64, 48, 0));
        assert_eq!(job.main.options.k, 2);
        assert_eq!(job.main.key, "kbuffer:k=2");
        assert!(job.compare.is_none());
        assert_eq!(job.camera.eye, glam::Vec3::new(0.0, 0.0, 2.0));
    }

    #[test]
    fn bad_requests_say_what_is_wrong() {
        let cases: [(String, &str); 10] = [
            ("not json".into(), "malformed message"),
            (r#"{"type": "shout"}"#.into(), "unknown variant"),
            (request(|v| v["width"] = json!(0)), "width 0 is outside"),
            (
                request(|v| v["height"] = json!(5000)),
                "height 5000 is outside",
            ),
            (request(|v| v["frame"] = json!(999)), "frame 999"),
            (
                request(|v| v["camera"]["up"] = json!([0, 0, 1])),
                "camera.up",
            ),
            (request(|v| v["camera"]["near"] = json!(-1)), "camera.near"),
            (request(|v| v["method"] = json!("nope")), "nope"),
            (
                request(|v| v["options"] = json!({"budget": "50%"})),
                "budget",
            ),
            (request(|v| v["options"] = json!({"k": "0"})), "k"),
        ];
        for (text, expected) in cases {
            let e = refused(&text);
            assert!(e.contains(expected), "{text}: {e}");
        }
        assert!(
            refused(&request(
                |v| v["options"] = json!({"weights": "/etc/passwd"})
            ))
            .contains("built into strata")
        );
        assert!(refused(&request(|v| v["extra"] = json!(1))).contains("unknown field"));
        let e = refused(&request(|v| {
            v["compare"] = json!({"method": "abuffer", "options": {"k": "3"}})
        }));
        assert!(
            e.starts_with("reference: method abuffer does not take k"),
            "{e}"
        );
    }

    fn mfr_request(patch: impl FnOnce(&mut Value)) -> String {
        let mut v = json!({
            "type": "mfr", "id": 4, "width": 64, "height": 48,
            "camera": {"eye": [0, 0, 2], "target": [0, 0, 0], "up": [0, 1, 0],
                       "fovy_deg": 10, "near": 0.5, "far": 5},
        });
        patch(&mut v);
        v.to_string()
    }

    #[test]
    fn mfr_settings_are_checked_and_only_an_mfr_viewer_takes_them() {
        let scene = scene();
        let Ok(Request::Mfr(job)) = parse(&mfr_request(|_| {}), &scene, Mode::Mfr) else {
            panic!("valid settings");
        };
        assert_eq!(
            (job.id, job.width, job.fc_hz, job.audit),
            (4, 64, 30.0, false)
        );
        assert_eq!(job.composition, strata_mfr::Composition::Deep);
        // The eye moves; the projection stays the scene's.
        assert_eq!(job.camera.eye, glam::Vec3::new(0.0, 0.0, 2.0));
        assert_eq!(job.camera.fovy_deg, scene.camera.fovy_deg);
        let mfr_refused = |text: String| match parse(&text, &scene, Mode::Mfr) {
            Ok(r) => panic!("accepted {text}: {r:?}"),
            Err(e) => format!("{e:#}"),
        };
        for (text, expected) in [
            (
                mfr_request(|v| v["composition"] = json!("x")),
                "composition 'x'",
            ),
            (
                mfr_request(|v| v["migration"] = json!("x")),
                "migration 'x'",
            ),
            (mfr_request(|v| v["fc_hz"] = json!(0)), "fc_hz 0"),
            (mfr_request(|v| v["fc_hz"] = json!(1000)), "fc_hz 1000"),
            (
                mfr_request(|v| v["sc_interval_ms"] = json!(-1)),
                "sc_interval_ms -1",
            ),
            (mfr_request(|v| v["width"] = json!(0)), "width 0"),
            (
                mfr_request(|v| v["height"] = json!(3000)),
                "height 3000: multi-frame-rate",
            ),
            (
                mfr_request(|v| v["camera"]["eye"] = json!([0, 0, 0])),
                "camera",
            ),
            (request(|_| {}), "--mfr"),
            (
                json!({"type": "remote", "id": 1, "width": 8, "height": 8,
                       "camera": mfr_request(|_| {}).parse::<Value>().unwrap()["camera"]})
                .to_string(),
                "--nodes",
            ),
            (
                json!({"type": "pointer", "x": 1e9, "y": 0, "pressed": false}).to_string(),
                "pointer at",
            ),
        ] {
            let e = mfr_refused(text.clone());
            assert!(e.contains(expected), "{text}: {e}");
        }
        let pointer = json!({"type": "pointer", "x": 3.5, "y": 2, "pressed": true, "seq": 9});
        let Ok(Request::Pointer(p)) = parse(&pointer.to_string(), &scene, Mode::Mfr) else {
            panic!("a valid pointer event");
        };
        assert_eq!((p.x, p.y, p.pressed, p.seq), (3.5, 2.0, true, Some(9)));
        for text in [mfr_request(|_| {}), pointer.to_string()] {
            assert!(refused(&text).contains("strata view SCENE --mfr"), "{text}");
        }
    }

    #[test]
    fn remote_settings_are_checked_and_only_a_remote_viewer_takes_them() {
        let scene = scene();
        let remote = |patch: &dyn Fn(&mut Value)| {
            let mut v: Value = mfr_request(|_| {}).parse().unwrap();
            v["type"] = json!("remote");
            patch(&mut v);
            v.to_string()
        };
        let Ok(Request::Remote(job)) = parse(&remote(&|_| {}), &scene, Mode::Remote) else {
            panic!("valid settings");
        };
        // The whole camera is the page's, projection included.
        assert_eq!((job.id, job.width, job.max_fps), (4, 64, 30.0));
        assert_eq!(job.transfer, None, "the command line's transfer");
        let chosen = remote(&|v| {
            v["transfer"] = json!("depth-limited");
            v["layers"] = json!(6);
        });
        let Ok(Request::Remote(job)) = parse(&chosen, &scene, Mode::Remote) else {
            panic!("a transfer with its layers");
        };
        assert_eq!(
            job.transfer,
            Some((
                strata_remote::Transfer::DepthLimited {
                    layers: 6,
                    opacity_threshold: None
                },
                0
            ))
        );
        assert_eq!(
            (job.camera.fovy_deg, job.camera.near, job.camera.far),
            (10.0, 0.5, 5.0)
        );
        for (text, expected) in [
            (remote(&|v| v["max_fps"] = json!(0)), "max_fps 0"),
            (remote(&|v| v["max_fps"] = json!(1e9)), "max_fps 1000000000"),
            (remote(&|v| v["width"] = json!(2049)), "width 2049: remote"),
            (remote(&|v| v["camera"]["near"] = json!(-1)), "near"),
            (
                remote(&|v| v["composition"] = json!("deep")),
                "unknown field",
            ),
            (
                remote(&|v| v["transfer"] = json!("depth-limited")),
                "transfer: --transfer depth-limited needs --layers",
            ),
            (
                remote(&|v| v["transfer"] = json!("magic")),
                "unknown transfer 'magic'",
            ),
            (
                remote(&|v| {
                    v["transfer"] = json!("full");
                    v["tolerance"] = json!(2);
                }),
                "--tolerance applies to",
            ),
            (remote(&|v| v["layers"] = json!(4)), "go with a transfer"),
            (request(|_| {}), "displays render nodes"),
            (mfr_request(|_| {}), "--mfr"),
        ] {
            match parse(&text, &scene, Mode::Remote) {
                Ok(r) => panic!("accepted {text}: {r:?}"),
                Err(e) => assert!(format!("{e:#}").contains(expected), "{text}: {e:#}"),
            }
        }
        // Questions about the frame are every mode's.
        let inspect = json!({"type": "inspect", "x": 1, "y": 2}).to_string();
        assert!(matches!(
            parse(&inspect, &scene, Mode::Remote),
            Ok(Request::About(Probe::Pixel(1, 2, None)))
        ));
    }

    #[test]
    fn request_ids_are_found_in_refused_messages() {
        assert_eq!(request_id(&request(|v| v["width"] = json!(0))), Some(3));
        assert_eq!(request_id("garbage"), None);
    }

    #[test]
    fn view_toml_reads_back_as_the_same_camera() {
        let c = Camera {
            eye: glam::Vec3::new(0.1, -2.0 / 3.0, 1e-7),
            target: glam::Vec3::new(1.0 / 3.0, 0.0, -0.25),
            up: glam::Vec3::Y,
            fovy_deg: 37.5,
            near: 0.01,
            far: 100.0,
        };
        let text = view_toml(&c, 320, 200) + "\n[[objects]]\nbuiltin = \"cube\"\n";
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("v.toml");
        std::fs::write(&path, text).expect("write");
        let scene = strata_scene::open_scene(
            path.to_str().expect("utf-8"),
            &strata_scene::SearchPath::default(),
        )
        .expect("the pasted view is a valid scene");
        assert_eq!(scene.camera, c);
        assert_eq!((scene.width, scene.height), (320, 200));
    }

    #[test]
    fn frame_messages_put_the_header_first() {
        let part = |name, rows, bytes: &[u8]| Part {
            name,
            rows,
            bytes: bytes.to_vec(),
        };
        let m = frame_message(
            json!({"type": "frame"}),
            &[
                part("main", Some(2), b"PN"),
                part("main", Some(3), b"G"),
                part("deep", None, b"EXR"),
            ],
        );
        let n = u32::from_le_bytes(m[..4].try_into().expect("4 bytes")) as usize;
        let header: Value = serde_json::from_slice(&m[4..4 + n]).expect("JSON");
        assert_eq!(
            header["images"],
            json!([{"name": "main", "bytes": 2, "rows": 2},
                   {"name": "main", "bytes": 1, "rows": 3},
                   {"name": "deep", "bytes": 3}])
        );
        assert_eq!(&m[4 + n..], b"PNGEXR");
    }

    #[test]
    fn bands_cover_the_rows_once_and_are_never_thin() {
        for height in [1, 63, 64, 127, 128, 180, 720, 721, 4096] {
            for threads in [0, 1, 2, 3, 16] {
                let b = bands(height, threads);
                assert_eq!(b.first().map(|r| r.start), Some(0));
                assert_eq!(b.last().map(|r| r.end), Some(height));
                assert!(b.windows(2).all(|w| w[0].end == w[1].start), "{b:?}");
                assert!(
                    b.len() <= threads.max(1),
                    "{height} rows, {threads} threads: {b:?}"
                );
                if b.len() > 1 {
                    assert!(b.iter().all(|r| r.len() >= MIN_BAND_ROWS as usize), "{b:?}");
                }
            }
        }
        assert_eq!(bands(180, 2), [0..90, 90..180]);
        assert_eq!(bands(720, 16).len(), 11);
    }

    #[test]
    fn an_image_sent_in_bands_is_the_image() {
        let (w, h) = (5u32, 200u32);
        let data = (0..w * h * 3).map(|i| (i * 31 % 253) as u8).collect();
        let image = strata_core::Rgb8Image::from_raw(w, h, data).expect("size");
        let small = strata_core::Rgb8Image::filled(w, 10, [9, 8, 7]);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .expect("pool");
        let parts = pool
            .install(|| encode_pngs(&[("main", image.clone()), ("bad", small.clone())]))
            .expect("encoded");
        let names: Vec<_> = parts.iter().map(|p| (p.name, p.rows)).collect();
        assert_eq!(
            names,
            [
                ("main", Some(66)),
                ("main", Some(67)),
                ("main", Some(67)),
                ("bad", Some(10))
            ]
        );
        for (name, want) in [("main", &image), ("bad", &small)] {
            let mut stacked = Vec::new();
            for p in parts.iter().filter(|p| p.name == name) {
                let mut reader = png::Decoder::new(std::io::Cursor::new(&p.bytes))
                    .read_info()
                    .expect("a PNG");
                let mut buf = vec![0; reader.output_buffer_size().expect("size")];
                let info = reader.next_frame(&mut buf).expect("a frame");
                assert_eq!((info.width, Some(info.height)), (w, p.rows));
                stacked.extend_from_slice(&buf[..info.buffer_size()]);
            }
            assert_eq!(stacked, want.as_bytes(), "{name}");
        }
        assert_eq!(
            Part::image_bytes(&parts, "main"),
            parts[..3].iter().map(|p| p.bytes.len()).sum::<usize>()
        );
    }
}
