//! The one trait every fragment store implements, and the driver that times its passes.

use std::time::Instant;

use strata_core::{DeepFrame, DeepFrameError, DepthStats, PassTimings, Rgb8Image, RunLimit};
use strata_raster::{FrameInput, Rasterizer, SetupStats};

/// Why a method could not render a frame.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// A buffer could not be allocated.
    #[error("cannot allocate {what} ({:.1} GiB): {hint}", *.bytes as f64 / (1u64 << 30) as f64)]
    OutOfMemory {
        /// Which buffer.
        what: String,
        /// How many bytes it needed.
        bytes: u64,
        /// What to do about it.
        hint: &'static str,
    },
}

/// A vector of `n` default values, allocated fallibly and filled in parallel.
pub(crate) fn try_alloc<T: Default + Send>(
    n: usize,
    what: impl FnOnce() -> String,
    hint: &'static str,
) -> Result<Vec<T>, StoreError> {
    use rayon::prelude::*;
    let mut v = Vec::new();
    v.try_reserve_exact(n)
        .map_err(|_| StoreError::OutOfMemory {
            what: what(),
            bytes: (n as u64).saturating_mul(size_of::<T>() as u64),
            hint,
        })?;
    v.par_extend((0..n).into_par_iter().map(|_| T::default()));
    Ok(v)
}

/// What a capture pass did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CaptureReport {
    /// Fragments the rasterizer produced (summed over passes for multi-pass methods).
    pub fragments_rasterized: u64,
    /// Fragments the store kept.
    pub fragments_stored: u64,
    /// Fragments lost to a full buffer; never silent — every method reports them here.
    pub dropped: u64,
    /// Fragments that did not fit but were not lost either: blended order-independently into a
    /// per-pixel tail behind the stored ones (the k-buffer's `--tail-blend`, as nvpro's OIT
    /// sample does). Counted apart from `dropped`; 0 for every other method.
    pub tail_blended: u64,
    /// Times the store had to grow its buffers and capture again.
    pub regrows: u32,
    /// Passes over the geometry: 1 for single-pass stores, 2 with a counting pass, one per layer
    /// for depth peeling (regrows included).
    pub raster_passes: u32,
    /// What triangle setup culled, clipped and binned.
    pub setup: SetupStats,
}

/// A per-pixel value a method computed for the frame (the variable k-buffer's k and importance),
/// row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct PixelMap {
    /// What it is (`k`, `importance`): the file stem it is exported under.
    pub name: &'static str,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// One value per pixel.
    pub values: Vec<f32>,
}

/// A multi-fragment rendering method; see the crate docs.
///
/// # Capturing a frame in chunks
///
/// A frame is `clear`, then one or more `capture` calls, then `resolve` and/or `deep_frame`.
/// For a store whose [`Method::captures_in_chunks`] is true, several capture calls between a
/// clear and the export **accumulate**: capturing the frame's objects in any split — some objects
/// per call, or consecutive ranges of their triangles
/// ([`FrameInput::triangle_range`](strata_raster::FrameInput::triangle_range)), in order —
/// leaves the store holding what one capture of the whole frame would, and its DeepFrame is
/// bit-identical to one capture's. A capture therefore never resets what earlier captures of the
/// frame stored (counters, lists, regions); only `clear` does. Each [`CaptureReport`] covers its
/// own call, except `fragments_stored`, which counts what the store holds after it. Every exact
/// store that keeps fragments in one geometry pass holds this contract (tested over the registry
/// in `tests/chunked_capture.rs`) except TFSS, whose regrow restarts the frame; depth peeling
/// does not either, as it needs all the geometry in every peel.
pub trait Method: Send {
    /// The name it is selected by (`--method`).
    fn name(&self) -> &'static str;

    /// Resets per-pixel state for a `width` × `height` frame (the "clear" pass), allocating
    /// buffers on the first frame or when the size changes.
    fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError>;

    /// Rasterises `input` into the store (the "capture" pass). Implementations record their
    /// stages as `capture.<stage>` in `timings`.
    fn capture(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        timings: &mut PassTimings,
    ) -> Result<CaptureReport, StoreError>;

    /// Sorts and composites every pixel onto `background` (the "resolve" pass). Implementations
    /// record their stages as `resolve.<stage>` in `timings`.
    fn resolve(&mut self, background: [f32; 3], timings: &mut PassTimings) -> Rgb8Image;

    /// Captures `input` and resolves the frame onto `background`: what [`Method::capture`]
    /// followed by [`Method::resolve`] does, image, depth statistics and stored fragments alike.
    /// Records the `capture` and `resolve` passes, each followed by its stages, in `timings`.
    ///
    /// The default runs the two passes one after the other. A store whose per-pixel state is cut
    /// into the rasterizer's strips may fuse them instead: the linked list resolves each strip as
    /// soon as the strip's scan ends, on the same thread, while the strip's nodes are still in
    /// that core's cache. Such a store reports the fused pass's wall time split between
    /// `capture.raster` and `resolve` by the thread time each part took.
    fn capture_and_resolve(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        background: [f32; 3],
        timings: &mut PassTimings,
    ) -> Result<(CaptureReport, Rgb8Image), StoreError> {
        let start = Instant::now();
        let mut stages = PassTimings::new();
        let capture = self.capture(raster, input, &mut stages)?;
        timings.add("capture", start.elapsed());
        timings.extend(&stages);

        let start = Instant::now();
        let mut stages = PassTimings::new();
        let image = self.resolve(background, &mut stages);
        timings.add("resolve", start.elapsed());
        timings.extend(&stages);
        Ok((capture, image))
    }

    /// Captures `input` and exports what the store then holds as a DeepFrame, each run cut to
    /// `limit`: what [`Method::capture`] followed by [`Method::deep_frame`] and
    /// [`DeepFrame::limit_runs`] does (a render node's frame; the limit is the depth-limited
    /// transfer's, [`RunLimit::NONE`] for the others). Records the capture's stages in
    /// `timings`. `reuse`, a frame no longer needed, may lend its buffers to the export (a
    /// stream of frames then needs no fresh memory).
    ///
    /// The default runs the three one after the other (and lets `reuse` go); the linked list
    /// and the k-buffer fuse them as the linked list fuses [`Method::capture_and_resolve`], each
    /// strip gathering its rows' fragments, cut to the limit, as its scan ends (the
    /// `strip_export` module).
    fn capture_and_export(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        limit: RunLimit,
        timings: &mut PassTimings,
        reuse: Option<DeepFrame>,
    ) -> Result<(CaptureReport, Option<Result<DeepFrame, DeepFrameError>>), StoreError> {
        drop(reuse);
        let report = self.capture(raster, input, timings)?;
        let frame = self.deep_frame().map(|f| f.map(|f| f.limit_runs(limit)));
        Ok((report, frame))
    }

    /// Depth complexity of what the store holds, as seen by the last resolve.
    fn depth_stats(&self) -> Option<DepthStats>;

    /// Bytes of the buffers the method allocated for this frame (whether used or not).
    fn memory_bytes(&self) -> u64;

    /// Bytes of those buffers that hold this frame's data (a node pool's used nodes, say).
    fn used_memory_bytes(&self) -> u64 {
        self.memory_bytes()
    }

    /// Per-pixel maps the method computed for the last frame (none by default).
    fn pixel_maps(&self) -> Vec<PixelMap> {
        Vec::new()
    }

    /// The per-pixel learning features of the last frame, if the method gathered them (the
    /// variable k-buffer with [`crate::MethodOptions::features`]); none by default.
    fn feature_maps(&self) -> Option<&crate::kbuffer::FeatureMaps> {
        None
    }

    /// The captured fragments as a DeepFrame; `None` for methods that do not keep fragments.
    fn deep_frame(&self) -> Option<Result<DeepFrame, DeepFrameError>>;

    /// Whether capture calls between a clear and the export accumulate (see the trait docs);
    /// false by default.
    fn captures_in_chunks(&self) -> bool {
        false
    }
}

/// Everything one rendered frame produced.
#[derive(Clone, Debug)]
pub struct FrameResult {
    /// The resolved image.
    pub image: Rgb8Image,
    /// `clear`, `capture` (with `capture.*` stages) and `resolve`, in milliseconds when printed.
    pub timings: PassTimings,
    /// What capture did.
    pub capture: CaptureReport,
    /// Depth complexity, if the method knows it.
    pub depth: Option<DepthStats>,
    /// Bytes of the method's buffers.
    pub memory_bytes: u64,
    /// Bytes of them holding this frame's data.
    pub used_memory_bytes: u64,
}

/// Everything one exported frame produced: what a render node renders and then encodes.
#[derive(Clone, Debug)]
pub struct ExportResult {
    /// The captured fragments, sorted front to back per pixel.
    pub frame: DeepFrame,
    /// `clear` and `capture` (capture and export together, with their `capture.*` stages).
    pub timings: PassTimings,
    /// What capture did.
    pub capture: CaptureReport,
    /// Bytes of the method's buffers.
    pub memory_bytes: u64,
    /// Bytes of them holding this frame's data.
    pub used_memory_bytes: u64,
}

/// Why a frame could not be exported.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The store failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The store's fragments do not form a DeepFrame.
    #[error(transparent)]
    DeepFrame(#[from] DeepFrameError),
    /// The store keeps no fragment lists.
    #[error("method '{0}' exports no DeepFrame")]
    NoDeepFrame(&'static str),
}

/// Checks that `method` can export DeepFrames, before any real frame is spent on it: clears a
/// 1×1 frame, captures `input`'s camera with no objects in it, and exports. The error says why
/// not (a store that keeps no fragment lists, a store that failed).
pub fn check_exports(method: &mut dyn Method, input: &FrameInput<'_>) -> Result<(), ExportError> {
    let empty = FrameInput {
        objects: Vec::new(),
        width: 1,
        height: 1,
        ..input.clone()
    };
    method.clear(1, 1)?;
    method.capture(&mut Rasterizer::default(), &empty, &mut PassTimings::new())?;
    match method.deep_frame() {
        Some(frame) => frame.map(drop).map_err(ExportError::from),
        None => Err(ExportError::NoDeepFrame(method.name())),
    }
}

/// Runs clear → capture → export ([`Method::capture_and_export`]) and times the passes: a render
/// node's frame, each run cut to `limit`, in the buffers of `reuse` (a frame no longer needed)
/// where the store can. Runs on the current rayon pool, as [`render_frame`] does.
pub fn export_frame(
    method: &mut dyn Method,
    raster: &mut Rasterizer,
    input: &FrameInput<'_>,
    limit: RunLimit,
    reuse: Option<DeepFrame>,
) -> Result<ExportResult, ExportError> {
    let mut timings = PassTimings::new();
    let start = Instant::now();
    method.clear(input.width, input.height)?;
    timings.add("clear", start.elapsed());

    let start = Instant::now();
    let mut stages = PassTimings::new();
    let (capture, frame) = method.capture_and_export(raster, input, limit, &mut stages, reuse)?;
    timings.add("capture", start.elapsed());
    timings.extend(&stages);
    let frame = frame.ok_or(ExportError::NoDeepFrame(method.name()))??;
    Ok(ExportResult {
        frame,
        timings,
        capture,
        memory_bytes: method.memory_bytes(),
        used_memory_bytes: method.used_memory_bytes(),
    })
}

/// Runs clear → capture → resolve ([`Method::capture_and_resolve`]) and times each pass.
///
/// Runs on the current rayon pool; wrap it in `ThreadPool::install` to choose the thread count.
pub fn render_frame(
    method: &mut dyn Method,
    raster: &mut Rasterizer,
    input: &FrameInput<'_>,
    background: [f32; 3],
) -> Result<FrameResult, StoreError> {
    let mut timings = PassTimings::new();
    let start = Instant::now();
    method.clear(input.width, input.height)?;
    timings.add("clear", start.elapsed());

    let (capture, image) = method.capture_and_resolve(raster, input, background, &mut timings)?;

    Ok(FrameResult {
        image,
        timings,
        capture,
        depth: method.depth_stats(),
        memory_bytes: method.memory_bytes(),
        used_memory_bytes: method.used_memory_bytes(),
    })
}
