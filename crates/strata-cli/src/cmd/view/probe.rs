//! Answers to a page's questions about the frame it shows — a pixel's fragments, the whole
//! frame as a deep OpenEXR file — for both modes: the normal one asks its store's DeepFrame, the
//! multi-frame-rate one the composed frame's.

use axum::extract::ws::Message;
use glam::Mat4;
use serde_json::{Value, json};
use strata_core::{DeepFrame, ObjectId};
use strata_scene::Scene;

use super::protocol::{self, Probe};
use crate::images::deep_exr_bytes;

/// A frame a page shows, as the questions about it need it.
pub(crate) struct Shown<'a> {
    /// The request id it answered.
    pub(crate) id: u64,
    pub(crate) frame: &'a DeepFrame,
    /// What kept its fragments, for the page (`kbuffer`, `deep composition`).
    pub(crate) method: String,
    /// The camera: near and far planes, view and projection matrices (for the deep EXR).
    pub(crate) near_far: (f32, f32),
    pub(crate) view: Mat4,
    pub(crate) projection: Mat4,
    /// Who drew a fragment of this object — the client (multi-frame rate), the render node
    /// (remote) — if that is told.
    pub(crate) client: Option<&'a dyn Fn(ObjectId) -> String>,
}

/// The answer to `probe` about `shown`: a `pixel` text, a `deep` binary message, or an error.
pub(crate) fn answer(scene: &Scene, probe: Probe, shown: &Shown<'_>) -> Message {
    let id = shown.id;
    let error = |text: &str| Message::Text(protocol::error_json(Some(id), text).into());
    let (width, height) = (shown.frame.width(), shown.frame.height());
    match probe {
        Probe::Pixel(_, _, Some(asked)) if asked != id => error(&format!(
            "frame {asked} has been replaced by frame {id}; click again"
        )),
        Probe::Pixel(x, y, _) if x >= width || y >= height => error(&format!(
            "pixel {x},{y} is outside the {width}x{height} frame"
        )),
        Probe::Pixel(x, y, _) => Message::Text(pixel(scene, shown, x, y).into()),
        Probe::Deep => {
            match deep_exr_bytes(shown.frame, shown.near_far, shown.view, shown.projection) {
                Ok(bytes) => Message::Binary(
                    protocol::frame_message(
                        json!({"type": "deep", "frame": id}),
                        &[protocol::Part {
                            name: "deep",
                            rows: None,
                            bytes,
                        }],
                    )
                    .into(),
                ),
                Err(e) => error(&format!("cannot write the deep EXR: {e:#}")),
            }
        }
    }
}

/// The `pixel` message for `(x, y)`: its fragments front to back with their objects' names and,
/// where told, the client that drew each.
fn pixel(scene: &Scene, shown: &Shown<'_>, x: u32, y: u32) -> String {
    let fragments: Vec<Value> = shown
        .frame
        .pixel(x, y)
        .iter()
        .map(|f| {
            let name = scene
                .objects
                .iter()
                .find(|o| o.id == f.object)
                .map(|o| o.name.as_str());
            let mut v =
                json!({"depth": f.depth, "rgba": f.color.0, "object": f.object.0, "name": name});
            if let Some(client) = shown.client {
                v["client"] = json!(client(f.object));
            }
            v
        })
        .collect();
    json!({"type": "pixel", "frame": shown.id, "x": x, "y": y, "method": shown.method,
           "fragments": fragments})
    .to_string()
}
