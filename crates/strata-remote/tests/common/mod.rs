//! What the remote tests share: the scene, a service on a loopback port, a node's and a
//! display's configuration.

#![allow(dead_code, reason = "each test binary uses its own part")]

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use strata_remote::Transfer;
use strata_remote::display::{DisplayConfig, OnFault};
use strata_remote::node::NodeConfig;
use strata_scene::{Animation, Scene, SearchPath, open_scene};
use strata_stores::MethodOptions;
use strata_wire::{Codec, DecodeOptions};

/// The built-in `mixed` scene (opaque and translucent objects intersecting), still.
pub(crate) fn mixed() -> Arc<Scene> {
    Arc::new(open_scene("mixed", &SearchPath::new([])).expect("built-in scene"))
}

/// `mixed` turning 5° per frame about y.
pub(crate) fn turning_mixed() -> Arc<Scene> {
    let mut s = open_scene("mixed", &SearchPath::new([])).expect("built-in scene");
    s.animation = Some(Animation {
        frames: 72,
        rotate_deg_per_frame: glam::Vec3::new(0.0, 5.0, 0.0),
    });
    Arc::new(s)
}

/// An A-buffer node rendering `objects` (indices) of `scene`, recording nothing.
pub(crate) fn node_config(scene: &Arc<Scene>, objects: &[usize]) -> NodeConfig {
    NodeConfig {
        scene: scene.clone(),
        objects: objects.iter().map(|&i| scene.objects[i].id).collect(),
        method: "abuffer".into(),
        method_options: MethodOptions::default(),
        limits: DecodeOptions::default(),
        record: None,
    }
}

/// Binds `addr` and runs `serve_on` with the listener on a runtime of its own; returns the
/// bound address and the runtime (dropping or shutting it down ends the service). Bound
/// without `block_on`, so a service can be started from inside a display's observer.
pub(crate) fn serve_at<F, Fut>(addr: &str, serve_on: F) -> (String, tokio::runtime::Runtime)
where
    F: FnOnce(tokio::net::TcpListener) -> Fut,
    Fut: Future<Output = std::io::Result<()>> + Send + 'static,
{
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let std_listener = std::net::TcpListener::bind(addr).unwrap();
    std_listener.set_nonblocking(true).unwrap();
    let listener = {
        let _guard = runtime.enter();
        tokio::net::TcpListener::from_std(std_listener).unwrap()
    };
    let addr = listener.local_addr().unwrap().to_string();
    runtime.spawn(serve_on(listener));
    (addr, runtime)
}

/// A display of `frames` frames of `scene` at `size` from `nodes`: `deep-huff` (what `strata
/// display` asks for by default), two frames in flight, a 10 s timeout, holding a missing
/// node's last frame.
pub(crate) fn display_config(
    scene: &Arc<Scene>,
    nodes: Vec<String>,
    transfer: Transfer,
    frames: u64,
    (width, height): (u32, u32),
) -> DisplayConfig {
    DisplayConfig {
        scene: scene.clone(),
        nodes,
        transfer,
        codec: Codec::DeepHuff,
        tolerance: 0,
        first_frame: 0,
        frames,
        width,
        height,
        in_flight: 2,
        timeout: Duration::from_secs(10),
        on_fault: OnFault::Hold,
        limits: DecodeOptions::default(),
    }
}
