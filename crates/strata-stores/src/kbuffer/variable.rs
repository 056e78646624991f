//! The variable k-buffer (Tsopouridis 2021 §3.2.2, Algorithms 16–21): a per-pixel k under a memory budget
//! of M fragments, from importance maps, the Optimal-K oracle (§4.2.2, Algorithm 23), an analytic
//! error model or a learned one (ch. 4).
//!
//! # Layout
//!
//! ```text
//! counts:     [u32; w*h]   fragments per pixel (the counting pass)
//! importance: [f32; w*h]   I(p) (importance maps), or k(p)/N (Optimal-K: the thesis's label)
//! k:          [u32; w*h]   k(p)
//! regions:    Regions      S-buffer layout: offsets = prefix sum of the capacities, fill,
//!                          slots [Fragment; Σ capacity] (12 bytes each)
//! ```
//!
//! # Passes, `--k-from importance` (the default)
//!
//! | pass | timing | seed |
//! | --- | --- | --- |
//! | count fragments per pixel (geometry) | `capture.count` | Alg. 8 |
//! | importance map + `I_tot` (screen) | `capture.importance` | Alg. 16, [`super::importance`] |
//! | k from the budget (screen + reductions) | `capture.k` | Alg. 17, [`super::allocate`] |
//! | prefix sum of k → regions (screen) | `capture.prefix_sum` | Alg. 18–19 |
//! | keep the k(p) nearest by insertion (geometry) | `capture.capture` | Alg. 20 |
//! | composite the sorted regions (screen) | `resolve` | Alg. 21 |
//!
//! The budget is `M = options.budget.fragments(w·h, N)` with `N` the fragments counted, and the
//! allocation guarantees `Σ k = min(M, N)`, `k(p) ≤ count(p)`, and `k(p) ≥ 1` on every covered
//! pixel when `M` allows it ([`super::allocate`]). The thesis's hashed group counters of the prefix
//! sum are replaced by a plain parallel scan ([`crate::regions::exclusive_prefix_sum`]), and its
//! pixel synchronisation by the rasterizer's one-thread-per-strip rule.
//!
//! # Passes, `--k-from optimal`
//!
//! The oracle needs every fragment, sorted, and the background (its cost compares resolved
//! colours, [`FrameInput::background`]) before it can choose k — so this mode is an exact S-buffer
//! whose runs are truncated to the oracle's k, and costs what that costs:
//!
//! | pass | timing |
//! | --- | --- |
//! | count fragments per pixel (geometry) | `capture.count` |
//! | prefix sum of the counts → exact regions | `capture.prefix_sum` |
//! | store every fragment (geometry) | `capture.capture` |
//! | sort every run | `capture.sort` |
//! | Optimal-K greedy ([`optimal_k`](mod@super::optimal_k)) + truncate every run to its k | `capture.k` |
//! | composite | `resolve` |
//!
//! Truncating the sorted runs keeps exactly the fragments a second KeepNearest capture into
//! regions of k(p) would keep (the k(p) nearest), without a third geometry pass. What is reported
//! is what the oracle really needs: the memory of the exact store; the fragments it truncates
//! count as lost. It shows the quality reachable at budget M, not a method that runs in M.
//!
//! # Passes, `--k-from analytic` and `--k-from learned`
//!
//! The same two geometry passes as importance maps; the counting pass also gathers the feature
//! sums ([`super::features`]), and k comes from a model of each pixel's truncation error:
//!
//! | pass | timing |
//! | --- | --- |
//! | count fragments and feature sums (geometry) | `capture.count` |
//! | each pixel's model: the analytic [`Worth`] from its mean colour and alpha, or the network's (screen) | `capture.importance` |
//! | water-filling the worths to the budget ([`analytic_k_reusing`], its lists kept between frames), or the importance allocator for networks that predict an importance | `capture.k` |
//! | prefix sum, keep the k(p) nearest, composite | as for importance maps |
//!
//! # Features for a learned k
//!
//! With [`MethodOptions::features`] the counting pass also accumulates the per-pixel sums of
//! [`super::features`] (same geometry pass, more work per fragment), and the features are
//! finished for the frame's budget right after it (timed as `capture.features`). They are
//! exposed through [`Method::feature_maps`]. Without the option nothing is allocated or gathered.
//!
//! Both modes expose the per-pixel k map ([`VariableKBuffer::k_map`]) and importance map
//! ([`VariableKBuffer::importance_map`]); [`super::maps`] renders them as heat maps.

use std::time::Instant;

use rayon::prelude::*;

use strata_core::{DeepFrame, DeepFrameError, DepthStats, PassTimings, Rgb8Image};
use strata_raster::{FrameInput, Rasterizer};

use crate::count::FragmentCounts;
use crate::method::{CaptureReport, Method, PixelMap, StoreError};
use crate::options::{Budget, ImportanceParams, KFrom, MethodOptions};
use crate::regions::{Policy, RegionCapture, Regions};

use super::allocate::{Allocation, allocate_k};
use super::analytic::{AnalyticScratch, Worth, analytic_k_reusing};
use super::features::{FeatureAccumulator, FeatureCapture, FeatureMaps, FrameFeatures};
use super::importance::importance_map;
use super::learned::{LearnedModel, Target};
use super::optimal_k::optimal_k_into;

/// The name it is selected by.
pub const NAME: &str = "vkbuffer";

/// The variable k-buffer; see the module docs.
#[derive(Debug)]
pub struct VariableKBuffer {
    k_from: KFrom,
    budget: Budget,
    params: ImportanceParams,
    width: u32,
    height: u32,
    counts: FragmentCounts,
    importance: Vec<f32>,
    k: Vec<u32>,
    regions: Regions,
    allocation: Allocation,
    depth: Option<DepthStats>,
    /// The counting pass's feature sums: gathered (and allocated) only when
    /// [`VariableKBuffer::needs_sums`].
    sums: FeatureAccumulator,
    /// The feature maps, finished when [`MethodOptions::features`] asks for them.
    maps: FeatureMaps,
    /// Whether the feature maps are to be finished (`MethodOptions::features`).
    want_maps: bool,
    /// Each pixel's model (`--k-from analytic`).
    worth: Vec<Worth>,
    /// The error-curve allocation's candidate lists, kept between frames.
    analytic: AnalyticScratch,
    /// The network (`--k-from learned` only).
    model: Option<std::sync::Arc<LearnedModel>>,
}

impl VariableKBuffer {
    /// A variable k-buffer with `options.budget`, `options.k_from` and `options.importance`.
    pub fn new(options: &MethodOptions) -> Self {
        VariableKBuffer {
            k_from: options.k_from,
            budget: options.budget,
            params: options.importance,
            width: 0,
            height: 0,
            counts: FragmentCounts::new(),
            importance: Vec::new(),
            k: Vec::new(),
            regions: Regions::new(),
            allocation: Allocation::default(),
            depth: None,
            sums: FeatureAccumulator::new(),
            maps: FeatureMaps::new(),
            want_maps: options.features,
            worth: Vec::new(),
            analytic: AnalyticScratch::new(),
            model: (options.k_from == KFrom::Learned).then(|| {
                options
                    .weights
                    .clone()
                    .unwrap_or_else(LearnedModel::builtin)
            }),
        }
    }

    /// The network of `--k-from learned` (`None` in the other modes).
    pub fn model(&self) -> Option<&LearnedModel> {
        self.model.as_deref()
    }

    /// Where k comes from.
    pub fn k_from(&self) -> KFrom {
        self.k_from
    }

    /// Per-pixel fragment counts of the last capture, row-major.
    pub fn counts(&self) -> &[u32] {
        self.counts.counts()
    }

    /// Per-pixel k of the last frame, row-major.
    pub fn k_map(&self) -> &[u32] {
        &self.k
    }

    /// Per-pixel importance of the last capture, row-major: `I(p)` from the importance maps, or
    /// `k(p) / N` from Optimal-K (Tsopouridis 2021 §4.2.2: the label the learned k-buffer trains on).
    pub fn importance_map(&self) -> &[f32] {
        &self.importance
    }

    /// The budget `M`, fragments counted `N`, covered pixels and `Σ k` of the last frame
    /// (for Optimal-K, `Σ k` of the oracle).
    pub fn allocation(&self) -> Allocation {
        self.allocation
    }

    /// The regions (the kept fragments, sorted).
    pub fn regions(&self) -> &Regions {
        &self.regions
    }

    fn map_bytes(&self) -> u64 {
        let features = self.sums.memory_bytes() + self.maps.memory_bytes();
        ((self.importance.len() + self.k.len()) * 4) as u64
            + (self.worth.len() * std::mem::size_of::<Worth>()) as u64
            + self.analytic.memory_bytes()
            + self.counts.memory_bytes()
            + features
    }

    /// The counting pass: counts, and the feature sums when they are asked for.
    fn count(
        &mut self,
        prepared: &strata_raster::Prepared<'_, '_>,
        timings: &mut PassTimings,
    ) -> u64 {
        timings
            .time("capture.count", || {
                if self.needs_sums() {
                    prepared.rasterize(&mut FeatureCapture {
                        counts: &mut self.counts,
                        sums: &mut self.sums,
                    })
                } else {
                    prepared.rasterize(&mut self.counts)
                }
            })
            .fragments
    }
}

impl VariableKBuffer {
    /// Whether the counting pass gathers the feature sums: the error models read them, and the
    /// feature maps are finished from them.
    fn needs_sums(&self) -> bool {
        self.want_maps || matches!(self.k_from, KFrom::Analytic | KFrom::Learned)
    }

    /// The importance and k passes of every mode but Optimal-K: fills `importance`, `k` (and
    /// `worth` for the error models) and `allocation` from the counting pass's results.
    fn choose_k(&mut self, budget: u64, background: [f32; 3], timings: &mut PassTimings) {
        let (width, height) = (self.width, self.height);
        let pixels = width as usize * height as usize;
        let counts = self.counts.counts();
        if self.k_from == KFrom::Importance {
            timings.time("capture.importance", || {
                importance_map(counts, width, height, &self.params, &mut self.importance)
            });
            self.allocation = timings.time("capture.k", || {
                allocate_k(counts, &self.importance, budget, &mut self.k)
            });
            return;
        }
        // The error models: `needs_sums` holds, so the counting pass gathered the sums.
        let sums = &self.sums;
        self.worth.resize(pixels, Worth::at_most_one(0.0));
        let use_curve = match self.model.as_deref() {
            Some(model) => {
                timings.time("capture.importance", || {
                    let frame = FrameFeatures::of(sums, budget, background);
                    model.infer(sums, counts, &frame, &mut self.importance, &mut self.worth);
                });
                model.target == Target::ErrorCurve
            }
            None => {
                timings.time("capture.importance", || {
                    analytic_worths(
                        sums,
                        counts,
                        background,
                        &mut self.worth,
                        &mut self.importance,
                    )
                });
                true
            }
        };
        self.allocation = timings.time("capture.k", || {
            if use_curve {
                analytic_k_reusing(&mut self.analytic, counts, &self.worth, budget, &mut self.k)
            } else {
                allocate_k(counts, &self.importance, budget, &mut self.k)
            }
        });
    }
}

/// The analytic model of every pixel from its sums ([`Worth`]), and as importance what keeping
/// only its nearest fragment would lose, `ê(1) = d·t` (0 where there is no choice).
fn analytic_worths(
    sums: &FeatureAccumulator,
    counts: &[u32],
    background: [f32; 3],
    worth: &mut [Worth],
    importance: &mut [f32],
) {
    worth
        .par_iter_mut()
        .zip(importance.par_iter_mut())
        .enumerate()
        .for_each(|(p, (w, i))| {
            let (mean, alpha) = sums.means(p, counts[p]);
            if counts[p] > 1 {
                *w = Worth::new(mean, alpha, background);
                *i = (w.contrast * (1.0 - f64::from(alpha.clamp(0.0, 1.0)))) as f32;
            } else {
                *w = Worth::at_most_one(Worth::contrast_of(mean, background));
                *i = 0.0;
            }
        });
}

impl Method for VariableKBuffer {
    fn name(&self) -> &'static str {
        NAME
    }

    fn clear(&mut self, width: u32, height: u32) -> Result<(), StoreError> {
        (self.width, self.height) = (width, height);
        self.counts.clear(width, height)?;
        if self.needs_sums() {
            self.sums.clear(width, height)?;
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
        let prepared = raster.prepare(input);
        timings.extend(prepared.timings());
        let (width, height) = (self.width, self.height);
        let pixels = width as usize * height as usize;

        let total = self.count(&prepared, timings);
        let budget = self.budget.fragments(pixels as u64, total);
        if self.want_maps {
            let (sums, maps) = (&self.sums, &mut self.maps);
            let counts = self.counts.counts();
            timings.time("capture.features", || {
                maps.compute(sums, counts, budget, input.background)
            });
        }
        self.importance.resize(pixels, 0.0);

        let captured = match self.k_from {
            KFrom::Importance | KFrom::Analytic | KFrom::Learned => {
                self.choose_k(budget, input.background, timings);
                let start = Instant::now();
                self.regions.with_capacities(width, height, &self.k)?;
                timings.add("capture.prefix_sum", start.elapsed());
                timings.time("capture.capture", || {
                    prepared.rasterize(&mut RegionCapture::new(
                        &mut self.regions,
                        Policy::KeepNearest,
                        None,
                    ))
                })
            }
            KFrom::Optimal => {
                let start = Instant::now();
                self.regions
                    .with_capacities(width, height, self.counts.counts())?;
                timings.add("capture.prefix_sum", start.elapsed());
                let captured = timings.time("capture.capture", || {
                    prepared.rasterize(&mut RegionCapture::new(
                        &mut self.regions,
                        Policy::Append,
                        None,
                    ))
                });
                timings.time("capture.sort", || self.regions.sort_runs());
                let covered = self.counts.counts().iter().filter(|&&c| c > 0).count() as u64;
                let sum = timings.time("capture.k", || {
                    optimal_k_into(&self.regions, input.background, budget, &mut self.k);
                    self.regions.truncate(&self.k);
                    let n = total.max(1) as f32;
                    self.importance
                        .par_iter_mut()
                        .zip(&self.k)
                        .for_each(|(i, &k)| *i = k as f32 / n);
                    self.k.par_iter().map(|&k| u64::from(k)).sum()
                });
                self.allocation = Allocation {
                    budget,
                    total,
                    covered,
                    sum,
                    rounds: 0,
                };
                captured
            }
        };
        Ok(CaptureReport {
            fragments_rasterized: total + captured.fragments,
            fragments_stored: self.regions.stored_count(),
            dropped: self.regions.lost(),
            raster_passes: 2,
            setup: prepared.setup_stats(),
            ..CaptureReport::default()
        })
    }

    fn resolve(&mut self, background: [f32; 3], _timings: &mut PassTimings) -> Rgb8Image {
        let (image, depth) = self.regions.resolve(background, false);
        self.depth = Some(depth);
        image
    }

    fn depth_stats(&self) -> Option<DepthStats> {
        self.depth.clone()
    }

    fn memory_bytes(&self) -> u64 {
        self.map_bytes() + self.regions.memory_bytes()
    }

    fn used_memory_bytes(&self) -> u64 {
        self.map_bytes() + self.regions.used_memory_bytes()
    }

    fn pixel_maps(&self) -> Vec<PixelMap> {
        let map = |name, values| PixelMap {
            name,
            width: self.width,
            height: self.height,
            values,
        };
        vec![
            map("k", self.k.iter().map(|&k| k as f32).collect()),
            map("importance", self.importance.clone()),
        ]
    }

    fn feature_maps(&self) -> Option<&FeatureMaps> {
        self.want_maps.then_some(&self.maps)
    }

    fn deep_frame(&self) -> Option<Result<DeepFrame, DeepFrameError>> {
        Some(self.regions.deep_frame())
    }
}
