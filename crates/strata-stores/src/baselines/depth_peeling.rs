//! Front-to-back depth peeling (Everitt 2001, "Interactive Order-Independent Transparency";
//! Tsopouridis 2021 §1.1, Jähne 2014 §1.1): one rasterisation per layer.
//!
//! # Layout
//!
//! ```text
//! state:  [PeelPixel; w*h]   36 bytes a pixel:
//!           last:  Fragment   the layer peeled in the previous pass (the thesis's second Z-buffer)
//!           taken: u32        copies of `last` peeled so far (0: nothing peeled yet)
//!           best:  Fragment   nearest fragment behind `last` seen this pass (the ordinary Z-buffer)
//!           eq:    u32        copies of `last` seen this pass
//!           count: u32        layers peeled at this pixel
//! accum:  [[f32; 4]; w*h]    colour accumulated front to back, and the transmittance T
//! peeled: [(u32, Fragment)]  every peeled fragment with its pixel, layer after layer (kept only
//!                            to hand out a DeepFrame; see [`DepthPeeling::keep_layers`])
//! ```
//!
//! # Passes
//!
//! - **clear**: nothing peeled, `accum = (0, 0, 0, T = 1)`.
//! - **peel** (`capture.peel`, once per layer): a geometry pass keeps, per pixel, the nearest
//!   fragment strictly behind the layer peeled by the previous pass — the second depth test of
//!   depth peeling. A GPU re-runs the vertex stage (and setup) every pass; here the rasterizer's
//!   [`strata_raster::Prepared`] frame is scanned again, so vertex and setup run once and each pass
//!   costs the scan only.
//! - **blend** (`capture.blend`, a screen-space pass after each peel): the new layer is composited
//!   under what is already accumulated, front to back: `C += T·α·c`, `T *= 1 − α` — the
//!   arithmetic of [`strata_core::composite::over_front_to_back`], operation for operation, so with
//!   every layer peeled the image is bit-identical to the A-buffer's.
//! - Peeling stops when a pass finds no fragment anywhere, or after
//!   [`MethodOptions::max_layers`] layers (0 = unlimited). The fragments never reached are reported
//!   as `dropped`. [`DepthPeeling::layers`] and [`DepthPeeling::passes`] say how many layers and
//!   geometry passes it took.
//! - **resolve**: `C + T · background` per pixel (or `C` alone once `T` reached 0, as the shared
//!   resolve stops there).
//!
//! # Exactness: coplanar fragments
//!
//! Classic depth peeling compares depths only: a fragment is peeled if its depth is strictly
//! greater than the previous layer's. Two fragments at the same depth (coplanar faces of two
//! objects) then peel as one — the depth test keeps one, the next pass rejects the other — and a
//! fragment is lost. Here "behind" is the strict total order of
//! [`strata_core::Fragment::order_key`] (depth, then object, then colour), so coplanar fragments
//! of different objects are all peeled, one per pass, in the canonical order. Fragments with
//! equal keys are identical; the pass counts how many copies of the last layer it sees (`eq`) and
//! peels another copy while some remain, so even duplicates are not lost. The peeled layers of
//! a pixel are therefore exactly its sorted run, and [`Method::deep_frame`] returns the same
//! DeepFrame as the A-buffer; with `max_layers = L` it holds each pixel's `L` nearest fragments.

use std::time::Instant;

use rayon::prelude::*;
use strata_core::fragment::unorm8;
use strata_core::{
    DeepFrame, DeepFrameError, DepthStats, Fragment, ObjectId, PassTimings, Rgb8Image, Rgba8,
    composite,
};
use strata_raster::{CaptureTarget, FragmentSink, FrameInput, Rasterizer, StripLayout};

use super::peeled::peeled_to_deep_frame;
use crate::method::{CaptureReport, Method, StoreError, try_alloc};
use crate::options::MethodOptions;
use crate::resolve::resolve_pixels;

/// The name the method is selected by.
pub const NAME: &str = "depth-peeling";

/// Pixels per parallel task in the screen-space passes.
const PIXELS_PER_TASK: usize = 8 * 1024;

/// "No fragment this pass": farther than any real fragment (depths are in `[0, 1]`).
const NONE: Fragment = Fragment {
    depth: f32::INFINITY,
    color: Rgba8([0; 4]),
    object: ObjectId(0),
};

/// One pixel's peeling state; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PeelPixel {
    last: Fragment,
    taken: u32,
    best: Fragment,
    eq: u32,
    count: u32,
}

impl Default for PeelPixel {
    fn default() -> Self {
        PeelPixel {
            last: Fragment::default(),
            taken: 0,
            best: NONE,
            eq: 0,
            count: 0,
        }
    }
}

/// Composites `c` under the accumulated `acc = (C, T)`: the front-to-back OVER step.
#[inline(always)]
pub(crate) fn blend_front(acc: &mut [f32; 4], c: Rgba8) {
    let [r, g, b, a] = c.to_unorm();
    let w = acc[3] * a;
    acc[0] += w * r;
    acc[1] += w * g;
    acc[2] += w * b;
    acc[3] *= 1.0 - a;
}

/// Front-to-back depth peeling; see the module docs.
#[derive(Debug)]
pub struct DepthPeeling {
    max_layers: u32,
    keep_layers: bool,
    width: u32,
    height: u32,
    state: Vec<PeelPixel>,
    accum: Vec<[f32; 4]>,
    peeled: Vec<(u32, Fragment)>,
    layers: u32,
    passes: u32,
    depth: Option<DepthStats>,
}

impl DepthPeeling {
    /// Peels up to [`MethodOptions::max_layers`] layers (0: until none is left) and keeps them
    /// for the DeepFrame.
    pub fn new(options: &MethodOptions) -> Self {
        DepthPeeling {
            max_layers: options.max_layers,
            keep_layers: true,
            width: 0,
            height: 0,
            state: Vec::new(),
            accum: Vec::new(),
            peeled: Vec::new(),
            layers: 0,
            passes: 0,
            depth: None,
        }
    }

    /// Whether peeled fragments are kept to hand out a DeepFrame (the default). Without them the
    /// method holds only its per-pixel state and accumulator, as a GPU implementation does, and
    /// [`Method::deep_frame`] returns `None`.
    pub fn keep_layers(mut self, keep: bool) -> Self {
        self.keep_layers = keep;
        self
    }

    /// Layers peeled in the last capture (passes that found a fragment somewhere).
    pub fn layers(&self) -> u32 {
        self.layers
    }

    /// Geometry passes of the last capture: the layers, plus the final pass that found nothing
    /// unless `max_layers` stopped it first.
    pub fn passes(&self) -> u32 {
        self.passes
    }

    /// The blend pass after a peel: composites each pixel's new layer; returns how many pixels
    /// had one.
    fn blend_layer(&mut self) -> u64 {
        let keep = self.keep_layers;
        let parts: Vec<(u64, Vec<(u32, Fragment)>)> = self
            .state
            .par_chunks_mut(PIXELS_PER_TASK)
            .zip(self.accum.par_chunks_mut(PIXELS_PER_TASK))
            .with_max_len(1)
            .enumerate()
            .map(|(task, (state, accum))| {
                let mut out = Vec::new();
                let mut n = 0u64;
                for (i, (s, acc)) in state.iter_mut().zip(accum.iter_mut()).enumerate() {
                    let layer = if s.taken > 0 && s.eq > s.taken {
                        s.taken += 1; // another copy of an identical fragment
                        s.last
                    } else if s.best.depth.is_finite() {
                        s.last = s.best;
                        s.taken = 1;
                        s.best
                    } else {
                        s.eq = 0;
                        continue;
                    };
                    s.eq = 0;
                    s.best = NONE;
                    s.count += 1;
                    blend_front(acc, layer.color);
                    n += 1;
                    if keep {
                        out.push(((task * PIXELS_PER_TASK + i) as u32, layer));
                    }
                }
                (n, out)
            })
            .collect();
        let mut total = 0;
        for (n, out) in parts {
            total += n;
            self.peeled.extend_from_slice(&out);
        }
        total
    }
}

/// Peels one strip of rows.
#[derive(Debug)]
pub struct PeelSink<'a> {
    first_pixel: usize,
    state: &'a mut [PeelPixel],
}

impl FragmentSink for PeelSink<'_> {
    #[inline(always)]
    fn push(&mut self, pixel: u32, fragment: Fragment) {
        let s = &mut self.state[pixel as usize - self.first_pixel];
        let key = fragment.order_key();
        if s.taken > 0 {
            let last = s.last.order_key();
            if key <= last {
                s.eq += u32::from(key == last);
                return;
            }
        }
        if key < s.best.order_key() {
            s.best = fragment;
        }
    }
}

impl CaptureTarget for DepthPeeling {
    type Sink<'s> = PeelSink<'s>;

    fn sinks(&mut self, layout: &StripLayout) -> Vec<PeelSink<'_>> {
        assert_eq!(
            (layout.width, layout.height),
            (self.width, self.height),
            "clear before capture"
        );
        layout
            .split_mut(&mut self.state)
            .enumerate()
            .map(|(s, state)| PeelSink {
                first_pixel: layout.pixels(s).start,
                state,
            })
            .collect()
    }
}

impl Method for DepthPeeling {
    fn name(&self) -> &'static str {
        NAME
    }

    fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        let pixels = width as usize * height as usize;
        (self.width, self.height) = (width, height);
        if self.state.len() != pixels {
            self.state = Vec::new();
            self.accum = Vec::new();
            self.state = try_alloc(
                pixels,
                || format!("{pixels} peeling states"),
                "render a smaller image",
            )?;
            self.accum = try_alloc(
                pixels,
                || format!("{pixels} colour accumulators"),
                "render a smaller image",
            )?;
        }
        self.state
            .par_iter_mut()
            .for_each(|s| *s = PeelPixel::default());
        self.accum
            .par_iter_mut()
            .for_each(|a| *a = [0.0, 0.0, 0.0, 1.0]);
        self.peeled.clear();
        (self.layers, self.passes) = (0, 0);
        self.depth = None;
        Ok(())
    }

    fn capture(
        &mut self,
        raster: &mut Rasterizer,
        input: &FrameInput<'_>,
        timings: &mut PassTimings,
    ) -> Result<CaptureReport, StoreError> {
        let prepared = raster.prepare(input);
        timings.extend(prepared.timings());
        let (mut rasterized, mut stored) = (0u64, 0u64);
        let mut per_pass = None;
        while self.max_layers == 0 || self.layers < self.max_layers {
            let start = Instant::now();
            let stats = prepared.rasterize(self);
            timings.add("capture.peel", start.elapsed());
            self.passes += 1;
            rasterized += stats.fragments;
            per_pass.get_or_insert(stats.fragments);

            let start = Instant::now();
            let peeled = self.blend_layer();
            timings.add("capture.blend", start.elapsed());
            if peeled == 0 {
                break;
            }
            self.layers += 1;
            stored += peeled;
        }
        // The loop runs at least one pass (max_layers is 0 or at least 1).
        let total = per_pass.unwrap_or(0);
        Ok(CaptureReport {
            fragments_rasterized: rasterized,
            fragments_stored: stored,
            dropped: total - stored,
            regrows: 0,
            raster_passes: self.passes,
            setup: prepared.setup_stats(),
            ..CaptureReport::default()
        })
    }

    fn resolve(&mut self, background: [f32; 3], _timings: &mut PassTimings) -> Rgb8Image {
        let bg = composite::background_pixel(background);
        let (state, accum) = (&self.state, &self.accum);
        let (image, depth) = resolve_pixels(self.width, self.height, |p| {
            let n = state[p].count;
            if n == 0 {
                return (bg, 0);
            }
            let [r, g, b, t] = accum[p];
            let c = if t <= 0.0 {
                [r, g, b]
            } else {
                [
                    r + t * background[0],
                    g + t * background[1],
                    b + t * background[2],
                ]
            };
            ([unorm8(c[0]), unorm8(c[1]), unorm8(c[2])], n)
        });
        self.depth = Some(depth);
        image
    }

    fn depth_stats(&self) -> Option<DepthStats> {
        self.depth.clone()
    }

    /// Per-pixel state and accumulator, plus the kept layers (16 bytes a peeled fragment).
    fn memory_bytes(&self) -> u64 {
        (self.state.len() * size_of::<PeelPixel>()
            + self.accum.len() * size_of::<[f32; 4]>()
            + self.peeled.len() * size_of::<(u32, Fragment)>()) as u64
    }

    fn deep_frame(&self) -> Option<Result<DeepFrame, DeepFrameError>> {
        if !self.keep_layers {
            return None;
        }
        let counts: Vec<u32> = self.state.par_iter().map(|s| s.count).collect();
        Some(peeled_to_deep_frame(
            self.width,
            self.height,
            &counts,
            &self.peeled,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frag(depth: f32, rgba: [u8; 4], o: u32) -> Fragment {
        Fragment {
            depth,
            color: Rgba8(rgba),
            object: ObjectId(o),
        }
    }

    /// Runs peel passes over a fixed fragment list (bypassing the rasterizer) until a pass finds
    /// nothing.
    fn peel_all(dp: &mut DepthPeeling, layout: &StripLayout, frags: &[(u32, Fragment)]) {
        loop {
            let mut sinks = dp.sinks(layout);
            for &(p, f) in frags {
                sinks[p as usize / layout.pixels_per_strip()].push(p, f);
            }
            drop(sinks);
            if dp.blend_layer() == 0 {
                break;
            }
            dp.layers += 1;
        }
    }

    #[test]
    fn coplanar_and_duplicate_fragments_are_all_peeled_in_order() {
        let layout = StripLayout {
            width: 2,
            height: 1,
            strip_height: 1,
        };
        let mut dp = DepthPeeling::new(&MethodOptions::default());
        dp.clear(2, 1).unwrap();
        let a = frag(0.5, [255, 0, 0, 100], 2);
        let b = frag(0.5, [0, 255, 0, 100], 1); // same depth, lower object: in front of a
        let c = frag(0.25, [0, 0, 255, 60], 3);
        let frags = [(0, a), (0, b), (0, c), (0, a), (1, c)];
        peel_all(&mut dp, &layout, &frags);
        assert_eq!(dp.layers, 4);
        let df = dp.deep_frame().unwrap().unwrap();
        assert_eq!(df.run(0).iter().collect::<Vec<_>>(), vec![c, b, a, a]);
        assert_eq!(df.run(1).iter().collect::<Vec<_>>(), vec![c]);
        let img = dp.resolve([1.0, 1.0, 1.0], &mut PassTimings::new());
        let want = composite::resolve_pixel([c.color, b.color, a.color, a.color], [1.0; 3]);
        assert_eq!(img.pixel(0, 0), want);
        // state (36 B) and accumulator (16 B) per pixel, 16 B per kept fragment
        assert_eq!(size_of::<PeelPixel>(), 36);
        assert_eq!(dp.memory_bytes(), 2 * 36 + 2 * 16 + 5 * 16);
    }
}
