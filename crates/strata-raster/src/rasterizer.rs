//! The rasterizer driver: owns the stage buffers and runs vertex → setup → scan.

use std::time::Instant;

use rayon::prelude::*;
use strata_core::{ObjectId, PackedNormal, PassTimings, Rgba8, Shading, fragment::unorm8};

use crate::frame::{FragmentOutput, FrameInput};
use crate::lanes::{LaneJob, Permute};
use crate::scan::{Shade, scan_triangle};
pub use crate::setup::SetupStats;
use crate::setup::{BinnedTriangle, Chunk, PixelFragment, SetupContext, setup_chunk};
use crate::shade_lanes::SpanShader;
use crate::sink::{CaptureTarget, FragmentSink, StripLayout};
use crate::vertex::{Attrs, MAX_SIDE, ObjectTransform, ScreenPos, Viewport, transform_vertices};

/// Vertices per parallel work item in the vertex stage.
const VERTICES_PER_TASK: usize = 4096;

/// Tuning knobs; the defaults are what the benchmarks measured best on 2–16 cores.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RasterConfig {
    /// Rows per strip, the unit of parallel scan conversion; a power of two.
    pub strip_height: u32,
    /// Triangles per setup chunk, the unit of parallel setup.
    pub chunk_triangles: usize,
}

impl Default for RasterConfig {
    fn default() -> Self {
        RasterConfig {
            strip_height: 16,
            chunk_triangles: 16 * 1024,
        }
    }
}

/// What one scan pass produced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RasterStats {
    /// Fragments pushed into the target.
    pub fragments: u64,
}

/// The CPU rasterizer; see the crate docs. Reuse one across frames to reuse its buffers.
#[derive(Debug, Default)]
pub struct Rasterizer {
    config: RasterConfig,
    screen: Vec<ScreenPos>,
    codes: Vec<u8>,
    attrs: Vec<Attrs>,
    chunks: Vec<Chunk>,
}

/// A frame after the vertex and setup stages, ready to be scanned into one or more targets.
#[derive(Debug)]
pub struct Prepared<'r, 'a> {
    input: &'r FrameInput<'a>,
    chunks: &'r [Chunk],
    shades: Vec<(Shade, bool)>,
    layout: StripLayout,
    setup: SetupStats,
    timings: PassTimings,
}

impl Rasterizer {
    /// A rasterizer with the given configuration.
    ///
    /// # Panics
    /// If `strip_height` is not a power of two, or `chunk_triangles` is zero or ≥ 2^27 (a bin
    /// entry holds a chunk's binned pieces, up to six a triangle, and its strip's micro-triangle
    /// fragments, up to 32 a triangle, in 32 bits each: (2^27 − 1) · 32 < 2^32).
    pub fn new(config: RasterConfig) -> Self {
        assert!(
            config.strip_height.is_power_of_two(),
            "strip_height must be a power of two"
        );
        assert!(
            config.chunk_triangles > 0 && config.chunk_triangles < 1 << 27,
            "chunk_triangles must be in 1..2^27"
        );
        Rasterizer {
            config,
            ..Self::default()
        }
    }

    /// The configuration.
    pub fn config(&self) -> RasterConfig {
        self.config
    }

    /// Runs the vertex and setup stages for `input`.
    ///
    /// Work runs on the current rayon pool (use `ThreadPool::install` to choose the thread count).
    ///
    /// # Panics
    /// If the image is empty or a side is longer than [`MAX_SIDE`], or an object has a
    /// different number of normals than positions.
    pub fn prepare<'r, 'a>(&'r mut self, input: &'r FrameInput<'a>) -> Prepared<'r, 'a> {
        assert!(input.width > 0 && input.height > 0, "empty image");
        assert!(
            input.width <= MAX_SIDE && input.height <= MAX_SIDE,
            "image sides are at most {MAX_SIDE} pixels"
        );
        let config = self.config;
        let vp = Viewport::new(input.width, input.height);
        let layout = StripLayout {
            width: input.width,
            height: input.height,
            strip_height: config.strip_height,
        };
        let mut timings = PassTimings::new();

        // ---- vertex stage -------------------------------------------------------------------
        let start = Instant::now();
        let mut vertex_base = Vec::with_capacity(input.objects.len());
        let mut total = 0usize;
        for o in &input.objects {
            assert_eq!(
                o.positions.len(),
                o.normals.len(),
                "one normal per position"
            );
            vertex_base.push(total);
            total += o.positions.len();
        }
        self.screen.resize(total, ScreenPos::default());
        self.codes.resize(total, 0);
        self.attrs.resize(total, Attrs::default());
        {
            let mut jobs = Vec::with_capacity(input.objects.len());
            let (mut ss, mut cs, mut atts) = (
                &mut self.screen[..],
                &mut self.codes[..],
                &mut self.attrs[..],
            );
            for (o, draw) in input.objects.iter().enumerate() {
                let n = draw.positions.len();
                let (s, srest) = std::mem::take(&mut ss).split_at_mut(n);
                let (c, crest) = std::mem::take(&mut cs).split_at_mut(n);
                let (a, arest) = std::mem::take(&mut atts).split_at_mut(n);
                jobs.push((o, s, c, a));
                (ss, cs, atts) = (srest, crest, arest);
            }
            jobs.into_par_iter().for_each(|(o, s, c, a)| {
                let draw = &input.objects[o];
                let t = ObjectTransform::new(input.view, draw.model, input.projection);
                let lit = draw.material.shading == Shading::Headlight;
                s.par_chunks_mut(VERTICES_PER_TASK)
                    .zip(c.par_chunks_mut(VERTICES_PER_TASK))
                    .zip(a.par_chunks_mut(VERTICES_PER_TASK))
                    .enumerate()
                    .for_each(|(k, ((s, c), a))| {
                        let first = k * VERTICES_PER_TASK;
                        let range = first..first + s.len();
                        transform_vertices(
                            &t,
                            &vp,
                            &draw.positions[range.clone()],
                            &draw.normals[range],
                            lit,
                            s,
                            c,
                            a,
                        );
                    });
            });
        }
        timings.add("capture.vertex", start.elapsed());

        // ---- setup and binning ----------------------------------------------------------------
        let start = Instant::now();
        let mut n_chunks = 0;
        for (o, draw) in input.objects.iter().enumerate() {
            let n = draw.triangles.len();
            let mut first = 0;
            while first < n {
                let end = (first + config.chunk_triangles).min(n);
                if self.chunks.len() == n_chunks {
                    self.chunks.push(Chunk::default());
                }
                self.chunks[n_chunks].reset(o, first..end, layout.count());
                n_chunks += 1;
                first = end;
            }
        }
        // Keep the allocations of unused chunks for later frames, but do not scan them.
        let chunks = &mut self.chunks[..n_chunks];
        let shades: Vec<(Shade, bool)> = input
            .objects
            .iter()
            .map(|o| {
                let c = o.material.color;
                let packed = input.output == FragmentOutput::PackedNormal;
                (
                    Shade {
                        rgb: [c[0], c[1], c[2]],
                        alpha: unorm8(c[3]),
                        flat: if packed {
                            Rgba8::from_bits(PackedNormal::NONE.to_bits())
                        } else {
                            Rgba8::from_unorm(c)
                        },
                        id: o.id,
                        packed,
                    },
                    o.material.shading == Shading::Headlight,
                )
            })
            .collect();
        let transforms: Vec<ObjectTransform> = input
            .objects
            .iter()
            .map(|o| ObjectTransform::new(input.view, o.model, input.projection))
            .collect();
        let (screen, codes, attrs) = (&self.screen, &self.codes, &self.attrs);
        // One job per chunk (and per strip below): work per item varies a lot, and rayon can
        // only balance it by stealing whole jobs.
        chunks.par_iter_mut().with_max_len(1).for_each(|chunk| {
            let o = chunk.object;
            let draw = &input.objects[o];
            let base = vertex_base[o];
            let range = base..base + draw.positions.len();
            let cx = SetupContext {
                transform: &transforms[o],
                lit: shades[o].1,
                shade: &shades[o].0,
                viewport: &vp,
                strip_shift: config.strip_height.trailing_zeros(),
            };
            setup_chunk(
                chunk,
                draw,
                &screen[range.clone()],
                &codes[range.clone()],
                &attrs[range],
                &cx,
            );
        });
        let mut setup = SetupStats::default();
        for c in chunks.iter() {
            setup.add(&c.stats);
        }
        timings.add("capture.setup", start.elapsed());

        Prepared {
            input,
            chunks: &self.chunks[..n_chunks],
            shades,
            layout,
            setup,
            timings,
        }
    }
}

impl Prepared<'_, '_> {
    /// The strips the image is cut into.
    pub fn layout(&self) -> &StripLayout {
        &self.layout
    }

    /// What setup culled, clipped and binned.
    pub fn setup_stats(&self) -> SetupStats {
        self.setup
    }

    /// Time spent in the vertex (`capture.vertex`) and setup (`capture.setup`) stages.
    pub fn timings(&self) -> &PassTimings {
        &self.timings
    }

    /// The frame this was prepared from.
    pub fn input(&self) -> &FrameInput<'_> {
        self.input
    }

    /// Scans every strip in parallel into `target`'s sinks.
    ///
    /// # Panics
    /// If the target returns a different number of sinks than there are strips.
    pub fn rasterize<T: CaptureTarget + ?Sized>(&self, target: &mut T) -> RasterStats {
        let sinks = target.sinks(&self.layout);
        assert_eq!(sinks.len(), self.layout.count(), "one sink per strip");
        let fragments = sinks
            .into_par_iter()
            .with_max_len(1)
            .enumerate()
            .map(|(s, mut sink)| {
                let n = self.scan_strip(s, &mut sink);
                sink.finish();
                n
            })
            .sum();
        RasterStats { fragments }
    }

    /// Scans strip `s`: every chunk's micro-triangle fragments and binned triangles for the strip,
    /// in primitive order. Compiled once per instruction set and chosen at run time with its lane
    /// width, like setup, so the larger triangles' lanes ([`SpanShader`]) run in the widest
    /// registers there are.
    fn scan_strip<S: FragmentSink>(&self, s: usize, sink: &mut S) -> u64 {
        crate::lanes::dispatch(StripScan {
            prepared: self,
            strip: s,
            sink,
        })
    }

    #[inline(always)]
    fn scan_strip_impl<S: FragmentSink, const L: usize>(&self, s: usize, sink: &mut S) -> u64 {
        let mut lanes = SpanShader::<L>::default();
        let rows = self.layout.rows(s);
        let rows = (rows.start as i32, rows.end as i32 - 1);
        let (w, h) = (self.layout.width as i32, self.layout.height as i32);
        let mut n = 0u64;
        for chunk in self.chunks {
            let (bin, frags) = (&chunk.bins[s], &chunk.frags[s][..]);
            if bin.is_empty() {
                n += replay(frags, self.shades[chunk.object].0.id, sink);
                continue;
            }
            let (shade, lit) = &self.shades[chunk.object];
            let job = BinScan {
                bin,
                frags,
                binned: &chunk.binned,
                rows,
                size: (w, h),
                shade,
            };
            n += if *lit {
                job.run::<S, true, L>(&mut lanes, sink)
            } else {
                job.run::<S, false, L>(&mut lanes, sink)
            };
        }
        n
    }
}

/// [`Prepared::scan_strip`]'s arguments, for [`crate::lanes::dispatch`].
struct StripScan<'p, 'r, 'a, S> {
    prepared: &'p Prepared<'r, 'a>,
    strip: usize,
    sink: &'p mut S,
}

impl<S: FragmentSink> LaneJob for StripScan<'_, '_, '_, S> {
    type Output = u64;

    #[inline(always)]
    fn run<const L: usize, P: Permute<L>>(self, _: P) -> u64 {
        self.prepared.scan_strip_impl::<S, L>(self.strip, self.sink)
    }
}

/// Pushes micro-triangle fragments into the sink.
#[inline(always)]
fn replay<S: FragmentSink>(frags: &[PixelFragment], object: ObjectId, sink: &mut S) -> u64 {
    sink.push_records(frags, object);
    frags.len() as u64
}

/// One chunk's bin for one strip, with everything its triangles refer to.
struct BinScan<'a> {
    bin: &'a [u64],
    frags: &'a [PixelFragment],
    binned: &'a [BinnedTriangle],
    rows: (i32, i32),
    size: (i32, i32),
    shade: &'a Shade,
}

impl BinScan<'_> {
    /// Replays micro-triangle records and scans binned triangles, in primitive order.
    #[inline(always)]
    fn run<S: FragmentSink, const LIT: bool, const L: usize>(
        &self,
        lanes: &mut SpanShader<L>,
        sink: &mut S,
    ) -> u64 {
        let (w, h) = self.size;
        let mut n = 0u64;
        let mut next = 0;
        for &entry in self.bin {
            let (r, cursor) = (entry as u32, (entry >> 32) as usize);
            n += replay(&self.frags[next..cursor], self.shade.id, sink);
            next = cursor;
            let t = &self.binned[r as usize];
            let attrs = [&t.attrs[0], &t.attrs[1], &t.attrs[2]];
            n += u64::from(scan_triangle::<S, LIT, L>(
                t.pos, attrs, self.rows, w, h, self.shade, lanes, sink,
            ));
        }
        n + replay(&self.frags[next..], self.shade.id, sink)
    }
}
