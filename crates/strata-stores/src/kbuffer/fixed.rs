//! The fixed-k k-buffer (Tsopouridis 2021 §3.2.1, Algorithms 13–15): the k nearest fragments of every
//! pixel, kept sorted by insertion in one geometry pass; optionally with nvpro's tail blend.
//!
//! # Layout
//!
//! ```text
//! regions: Regions, capacity k for every pixel     offsets [u32; w*h+1], fill [u32; w*h],
//!                                                  slots [Fragment; k*w*h] (12 bytes each)
//! tail:    [Tail; w*h]  (only with --tail-blend)   20 bytes a pixel, see below
//! ```
//!
//! # Passes
//!
//! - **clear** (Alg. 13): every region's fill to 0 (and every tail to empty).
//! - **capture** (Alg. 14, `capture.capture`): each fragment is inserted into its pixel's sorted
//!   region ([`Policy::KeepNearest`]); when the region is full the farthest of the k + 1 falls
//!   off — it is *evicted*. The rasterizer hands each strip of rows to one thread, which plays the
//!   part of the thesis's pixel synchronisation: no two threads touch one pixel.
//! - **resolve** (Alg. 15): the regions are already sorted, so each pixel is composited front to
//!   back with OVER directly (no sort), onto the background — or onto its tail.
//!
//! Every fragment beyond the k nearest is evicted exactly once, so the evictions are exactly
//! `Σ max(0, count(p) − k)`: reported as `dropped`, or as `tail_blended` with the tail blend.
//!
//! # Tail blend (`--tail-blend`)
//!
//! nvpro's `vk_order_independent_transparency` sample (its `oitLoop` and `oitInterlock` shaders
//! under `OIT_TAILBLEND`) does not throw evicted fragments away: the colour pass emits each
//! fragment that misses (or is pushed out of) the k frontmost as a premultiplied colour, which the
//! blend unit composites into the framebuffer (premultiplied OVER), and the composite pass then
//! blends the k sorted fragments over that. The result is approximate behind the k-th layer and
//! exact in front of it.
//!
//! The sample's tail is blended by the hardware with OVER in submission order, so it depends on
//! the order the triangles were drawn in. strata's images must not (the pipeline design), so the tail is
//! accumulated *order-independently*, as the weighted average of Bavoil & Myers (2008): per pixel
//!
//! ```text
//! premul[c] = Σ a_i · c_i      (8-bit a and c, exact integer sums: 3 × u32)
//! alpha     = Σ a_i            (u32)
//! neg_ln_t  = Σ −ln(1 − a_i/255) · 2^20   (fixed point, from a table; saturates at u32::MAX,
//!                                           where the tail is opaque: a_i = 255 puts it there)
//! ```
//!
//! and resolved as `T_tail = exp(−neg_ln_t / 2^20)`,
//! `C_tail = premul / (255 · alpha) · (1 − T_tail)`: the tail's colour is the alpha-weighted mean
//! of its fragments, its coverage exactly that of all of them together. Integer sums make the tail
//! bit-identical for any arrival order. The tail then serves as the pixel's background:
//! `pixel = OVER(k sorted fragments) onto (C_tail + T_tail · background)`, so a pixel with no
//! evicted fragment resolves exactly as without the tail blend, and one evicted fragment blends
//! exactly (up to the fixed point of `T_tail`). The tail's memory is reported on its own
//! ([`KBuffer::tail_memory_bytes`]) and included in [`Method::memory_bytes`].

use rayon::prelude::*;
use strata_core::{
    DeepFrame, DeepFrameError, DepthStats, Fragment, PassTimings, Rgb8Image, RunLimit, composite,
};
use strata_raster::{CaptureTarget, FragmentSink, FrameInput, Rasterizer, StripLayout};

use crate::method::{CaptureReport, Method, StoreError, try_alloc};
use crate::options::MethodOptions;
use crate::regions::{Policy, RegionCapture, RegionSink, Regions};
use crate::resolve::resolve_pixels;
use crate::strip_export::{self, SpareColumns, StripSlot};

/// The name it is selected by.
pub const NAME: &str = "kbuffer";

/// Fixed-point scale of the tail's `−ln T`.
const NEG_LN_SCALE: f64 = (1u64 << 20) as f64;

/// One pixel's order-independent tail; see the module docs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tail {
    /// `Σ a·r`, `Σ a·g`, `Σ a·b` of the evicted fragments (8-bit values).
    pub premul: [u32; 3],
    /// `Σ a`.
    pub alpha: u32,
    /// `Σ −ln(1 − a/255)` in units of 2^-20, saturating (u32::MAX = opaque).
    pub neg_ln_t: u32,
}

impl Tail {
    /// Adds one evicted fragment.
    #[inline(always)]
    fn add(&mut self, f: Fragment, neg_ln: &[u32; 256]) {
        let [r, g, b, a] = f.color.0.map(u32::from);
        self.premul[0] = self.premul[0].saturating_add(a * r);
        self.premul[1] = self.premul[1].saturating_add(a * g);
        self.premul[2] = self.premul[2].saturating_add(a * b);
        self.alpha = self.alpha.saturating_add(a);
        self.neg_ln_t = self.neg_ln_t.saturating_add(neg_ln[a as usize]);
    }

    /// The tail composited onto `background`: what the k sorted fragments are blended over.
    pub fn over(&self, background: [f32; 3]) -> [f32; 3] {
        if self.alpha == 0 {
            return background;
        }
        let t = if self.neg_ln_t == u32::MAX {
            0.0
        } else {
            (-f64::from(self.neg_ln_t) / NEG_LN_SCALE).exp()
        };
        let scale = (1.0 - t) / (255.0 * f64::from(self.alpha));
        std::array::from_fn(|c| {
            (f64::from(self.premul[c]) * scale + t * f64::from(background[c])) as f32
        })
    }
}

/// `−ln(1 − a/255) · 2^20`, rounded; `u32::MAX` for a = 255 (nothing behind shows through).
fn neg_ln_table() -> [u32; 256] {
    std::array::from_fn(|a| {
        if a == 255 {
            u32::MAX
        } else {
            (-(1.0 - a as f64 / 255.0).ln() * NEG_LN_SCALE).round() as u32
        }
    })
}

/// The fixed-k k-buffer; see the module docs.
#[derive(Debug)]
pub struct KBuffer {
    k: u32,
    tail_blend: bool,
    regions: Regions,
    tail: Vec<Tail>,
    neg_ln: [u32; 256],
    depth: Option<DepthStats>,
    /// The fused export's strip columns, kept for the next export.
    spare_columns: SpareColumns,
}

impl KBuffer {
    /// A k-buffer with `options.k` fragments a pixel, tail-blending if `options.tail_blend`.
    pub fn new(options: &MethodOptions) -> Self {
        Self::with_k(options.k, options.tail_blend)
    }

    /// A k-buffer keeping `k` fragments a pixel, tail-blending the others if `tail_blend`.
    pub fn with_k(k: u32, tail_blend: bool) -> Self {
        KBuffer {
            k,
            tail_blend,
            regions: Regions::new(),
            tail: Vec::new(),
            neg_ln: neg_ln_table(),
            depth: None,
            spare_columns: SpareColumns::default(),
        }
    }

    /// `k`.
    pub fn k(&self) -> u32 {
        self.k
    }

    /// Whether evicted fragments are tail-blended.
    pub fn tail_blend(&self) -> bool {
        self.tail_blend
    }

    /// The regions (the kept fragments).
    pub fn regions(&self) -> &Regions {
        &self.regions
    }

    /// Per-pixel tails, row-major (empty without the tail blend).
    pub fn tails(&self) -> &[Tail] {
        &self.tail
    }

    /// Bytes of the tail buffer (0 without the tail blend).
    pub fn tail_memory_bytes(&self) -> u64 {
        (self.tail.len() * size_of::<Tail>()) as u64
    }
}

impl KBuffer {
    /// Captures `input` into the regions (and tails); with `export`, each strip also gathers
    /// its regions as it finishes, cut to that limit, into the slots returned
    /// ([`crate::strip_export`]).
    fn capture_into(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        timings: &mut PassTimings,
        export: Option<RunLimit>,
    ) -> (CaptureReport, Option<Vec<StripSlot>>) {
        let prepared = raster.prepare(input);
        timings.extend(prepared.timings());
        let spare = &mut self.spare_columns;
        let mut slots = export.map(|limit| strip_export::slots(prepared.layout(), limit, spare));
        let export = slots.as_deref_mut();
        let stats = timings.time("capture.capture", || {
            if self.tail_blend {
                prepared.rasterize(&mut TailCapture {
                    regions: &mut self.regions,
                    tail: &mut self.tail,
                    neg_ln: &self.neg_ln,
                    export,
                })
            } else {
                let mut target = RegionCapture::new(&mut self.regions, Policy::KeepNearest, None);
                if let Some(e) = export {
                    target = target.exporting(e);
                }
                prepared.rasterize(&mut target)
            }
        });
        let evicted = self.regions.lost();
        let (dropped, tail_blended) = if self.tail_blend {
            (0, evicted)
        } else {
            (evicted, 0)
        };
        let report = CaptureReport {
            fragments_rasterized: stats.fragments,
            fragments_stored: self.regions.stored_count(),
            dropped,
            tail_blended,
            raster_passes: 1,
            setup: prepared.setup_stats(),
            ..CaptureReport::default()
        };
        (report, slots)
    }
}

impl Method for KBuffer {
    fn name(&self) -> &'static str {
        NAME
    }

    fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        self.regions.uniform(width, height, self.k)?;
        let pixels = width as usize * height as usize;
        if !self.tail_blend {
            self.tail = Vec::new();
        } else if self.tail.len() == pixels {
            self.tail.par_iter_mut().for_each(|t| *t = Tail::default());
        } else {
            self.tail = Vec::new();
            self.tail = try_alloc(
                pixels,
                || format!("{pixels} tail-blend accumulators"),
                "render a smaller image or drop --tail-blend",
            )?;
        }
        self.depth = None;
        Ok(())
    }

    fn capture(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        timings: &mut PassTimings,
    ) -> Result<CaptureReport, StoreError> {
        Ok(self.capture_into(raster, input, timings, None).0)
    }

    /// Fused: every strip gathers its regions (kept sorted) as its scan ends, and the frame is
    /// assembled from the strips (the `strip_export` module).
    fn capture_and_export(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        limit: RunLimit,
        timings: &mut PassTimings,
        reuse: Option<DeepFrame>,
    ) -> Result<(CaptureReport, Option<Result<DeepFrame, DeepFrameError>>), StoreError> {
        let (report, slots) = self.capture_into(raster, input, timings, Some(limit));
        let (width, height) = (self.regions.width(), self.regions.height());
        let frame = timings.time("capture.export", || {
            let slots = slots.expect("an exporting capture returns its slots");
            strip_export::assemble(width, height, slots, reuse, &mut self.spare_columns)
        });
        Ok((report, Some(frame)))
    }

    fn resolve(&mut self, background: [f32; 3], _timings: &mut PassTimings) -> Rgb8Image {
        if !self.tail_blend {
            let (image, depth) = self.regions.resolve(background, false);
            self.depth = Some(depth);
            return image;
        }
        let (width, height) = (self.regions.width(), self.regions.height());
        let bg = composite::background_pixel(background);
        let (regions, tail) = (&self.regions, &self.tail);
        let (image, depth) = resolve_pixels(width, height, |p| {
            let run = regions.stored(p);
            let t = &tail[p];
            let rgb = if t.alpha == 0 {
                if run.is_empty() {
                    bg
                } else {
                    composite::resolve_pixel(run.iter().map(|f| f.color), background)
                }
            } else {
                composite::resolve_pixel(run.iter().map(|f| f.color), t.over(background))
            };
            (rgb, run.len() as u32)
        });
        self.depth = Some(depth);
        image
    }

    fn depth_stats(&self) -> Option<DepthStats> {
        self.depth.clone()
    }

    fn memory_bytes(&self) -> u64 {
        self.regions.memory_bytes() + self.tail_memory_bytes()
    }

    fn used_memory_bytes(&self) -> u64 {
        self.regions.used_memory_bytes() + self.tail_memory_bytes()
    }

    fn deep_frame(&self) -> Option<Result<DeepFrame, DeepFrameError>> {
        Some(self.regions.deep_frame())
    }
}

/// KeepNearest regions plus per-pixel tails, as one capture target.
struct TailCapture<'a> {
    regions: &'a mut Regions,
    tail: &'a mut [Tail],
    neg_ln: &'a [u32; 256],
    /// One slot a strip to gather its regions into as it finishes, if any.
    export: Option<&'a mut [StripSlot]>,
}

/// One strip's regions and tails.
struct TailSink<'a> {
    regions: RegionSink<'a>,
    first_pixel: usize,
    tail: &'a mut [Tail],
    neg_ln: &'a [u32; 256],
}

impl FragmentSink for TailSink<'_> {
    #[inline(always)]
    fn push(&mut self, pixel: u32, fragment: Fragment) {
        if let Some(out) = self.regions.insert_nearest(pixel, fragment) {
            self.tail[pixel as usize - self.first_pixel].add(out, self.neg_ln);
        }
    }

    fn finish(&mut self) {
        self.regions.finish();
    }
}

impl CaptureTarget for TailCapture<'_> {
    type Sink<'s>
        = TailSink<'s>
    where
        Self: 's;

    fn sinks(&mut self, layout: &StripLayout) -> Vec<TailSink<'_>> {
        let neg_ln = self.neg_ln;
        self.regions
            .strips_exporting(
                layout,
                Policy::KeepNearest,
                None,
                self.export.as_deref_mut(),
            )
            .into_iter()
            .zip(layout.split_mut(self.tail))
            .enumerate()
            .map(|(s, (regions, tail))| TailSink {
                regions,
                first_pixel: layout.pixels(s).start,
                tail,
                neg_ln,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::{ObjectId, Rgba8};

    fn frag(depth: f32, rgba: [u8; 4]) -> Fragment {
        Fragment {
            depth,
            color: Rgba8(rgba),
            object: ObjectId(0),
        }
    }

    #[test]
    fn one_tail_fragment_blends_like_over() {
        let table = neg_ln_table();
        let mut t = Tail::default();
        t.add(frag(0.5, [255, 0, 0, 128]), &table);
        let a = 128.0 / 255.0;
        let got = t.over([0.0, 0.0, 1.0]);
        let want = [a, 0.0, 1.0 - a];
        for c in 0..3 {
            assert!((got[c] - want[c]).abs() < 1e-5, "{got:?} vs {want:?}");
        }
    }

    #[test]
    fn tail_is_order_independent_and_opaque_fragments_hide_the_background() {
        let table = neg_ln_table();
        let fs = [
            frag(0.1, [255, 0, 0, 100]),
            frag(0.2, [0, 255, 0, 30]),
            frag(0.3, [0, 0, 255, 200]),
        ];
        let mut a = Tail::default();
        let mut b = Tail::default();
        for f in fs {
            a.add(f, &table);
        }
        for f in fs.iter().rev() {
            b.add(*f, &table);
        }
        assert_eq!(a, b);
        // Coverage is that of all three: 1 − Π(1 − a_i).
        let t: f64 = fs
            .iter()
            .map(|f| 1.0 - f64::from(f.color.0[3]) / 255.0)
            .product();
        let white = a.over([1.0; 3]);
        let black = a.over([0.0; 3]);
        for c in 0..3 {
            assert!((f64::from(white[c] - black[c]) - t).abs() < 1e-5);
        }
        let mut opaque = a;
        opaque.add(frag(0.4, [10, 10, 10, 255]), &table);
        assert_eq!(opaque.neg_ln_t, u32::MAX);
        assert_eq!(opaque.over([1.0; 3]), opaque.over([0.0; 3]));
    }

    #[test]
    fn fully_transparent_tail_changes_nothing() {
        let mut t = Tail::default();
        t.add(frag(0.1, [255, 255, 255, 0]), &neg_ln_table());
        assert_eq!(t.over([0.25, 0.5, 0.75]), [0.25, 0.5, 0.75]);
    }
}
