//! Training data for a learned variable k-buffer: per-pixel features labelled with the Optimal-K
//! oracle's k, over several views and budgets of several scenes, written as NumPy arrays.
//!
//! # One view, every budget
//!
//! Each view of a scene is rasterized twice, as the variable k-buffer's Optimal-K mode does: a
//! counting pass that also gathers the feature sums ([`FeatureCapture`]), then an exact capture
//! of every fragment, sorted per pixel. Then, for each budget share `b`, `M = ⌊b · N⌋`, the oracle
//! gives k ([`optimal_k()`]) and the features are finished for that `M` ([`FeatureMaps::compute`]):
//! one labelled frame per (view, budget), all from one rasterization of the view.
//!
//! # Rows
//!
//! A frame contributes one row per covered pixel (count ≥ 1), or a seeded sample of
//! `pixels_per_frame` of them: the pixels with the smallest `hash(seed, frame, pixel)`, written in
//! pixel order. Labels ([`LABELS`]), per row:
//!
//! | label | definition |
//! | --- | --- |
//! | `k_opt` | the oracle's k, fragments |
//! | `kept_fraction` | `(k_opt − 1)/(count − 1)` for count ≥ 2 (0 if `k_opt` = 0, possible only when `M` < covered pixels); `k_opt` for count = 1 |
//! | `seed_label` | `k_opt / N`, the thesis's label (Tsopouridis 2021 Alg. 23 line 19) |
//! | `error_1` … `error_8` | `e(k) = ‖C(k) − C(count)‖`: how far the pixel's colour with its `k` nearest fragments is from its full colour (RGB, Euclidean, over the background; 0 for `k ≥ count`): the truncation-error curve, the same at every budget |
//!
//! # Files ([`Dataset::write`])
//!
//! ```text
//! features.npy  float32 [n, F]   F = FEATURE_COUNT, columns in FEATURES order
//! labels.npy    float32 [n, L]   columns in LABELS order
//! frame.npy     uint32  [n]      the row's frame id (manifest "frames")
//! scene.npy     uint32  [n]      the row's scene id (manifest "scenes"; families for splits)
//! pixel.npy     uint32  [n]      the row-major pixel index within its frame
//! manifest.json                  feature list and set, labels, scenes and families, views,
//!                                budgets, seed, per-frame M, N, C and Σk, and the shape,
//!                                type and FNV-1a 64 hash of every file above
//! ```

use std::path::Path;

use glam::{Mat3, Vec3};
use rayon::prelude::*;
use strata_core::composite;
use strata_core::npy::{self, NpyData};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::{Camera, Scene};
use strata_stores::count::FragmentCounts;
use strata_stores::kbuffer::features::{
    FEATURE_COUNT, FEATURE_SET, FeatureAccumulator, FeatureCapture, FeatureMaps, feature_names,
};
use strata_stores::kbuffer::optimal_k;
use strata_stores::regions::{Policy, RegionCapture, Regions};

use crate::procedural::mix;

/// Name and version of the dataset layout.
pub const DATASET_FORMAT: &str = "strata-dataset-2";

/// The label columns, in order; see the module docs.
pub const LABELS: [&str; 3 + CURVE_LEN] = [
    "k_opt",
    "kept_fraction",
    "seed_label",
    "error_1",
    "error_2",
    "error_3",
    "error_4",
    "error_5",
    "error_6",
    "error_7",
    "error_8",
];

/// Points of the truncation-error curve in the labels (`error_1` … `error_8`).
pub const CURVE_LEN: usize = 8;

/// Why a dataset could not be made or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DatasetError {
    /// A budget share outside `(0, 100] %`.
    #[error(
        "budget {0}: expected a share of the frame's fragments above 0 % and up to 100 %, such as 50"
    )]
    BadBudget(String),
    /// No views.
    #[error("at least one view is needed")]
    NoViews,
    /// A store could not allocate its buffers.
    #[error(transparent)]
    Store(#[from] strata_stores::StoreError),
    /// A file could not be written.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// What went wrong.
        source: std::io::Error,
    },
}

/// Parses a budget share given in percent (`50`, `50%`, `12.5`) into a fraction in `(0, 1]`.
pub fn parse_budget(s: &str) -> Result<f64, DatasetError> {
    let t = s.trim();
    match t.strip_suffix('%').unwrap_or(t).trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v <= 100.0 => Ok(v / 100.0),
        _ => Err(DatasetError::BadBudget(t.to_owned())),
    }
}

/// What to render and how to sample it.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSpec {
    /// Views per scene, evenly spaced on an orbit about the camera's up axis through its target;
    /// view 0 is the scene's own camera.
    pub views: u32,
    /// Budget shares of the frame's fragments, each in `(0, 1]`.
    pub budgets: Vec<f64>,
    /// Rows kept per frame at most (a seeded sample), or every covered pixel.
    pub pixels_per_frame: Option<usize>,
    /// Seed of the sampling.
    pub seed: u64,
}

impl Default for DatasetSpec {
    fn default() -> Self {
        DatasetSpec {
            views: 8,
            budgets: vec![0.3, 0.5, 0.7, 0.85],
            pixels_per_frame: None,
            seed: 0,
        }
    }
}

/// A scene of the dataset and the family it belongs to (the unit of a held-out split).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SceneInfo {
    /// Scene id (the values of `scene.npy`).
    pub id: u32,
    /// The scene's name.
    pub name: String,
    /// Its family: every resolution of one mesh, or every procedural scene, is one family.
    pub family: String,
    /// Image width and height.
    pub size: (u32, u32),
}

/// The family of a scene name: the name without a `-res…` suffix (`dragon-res2` → `dragon`),
/// and `procedural` for generated scenes.
pub fn family_of(name: &str) -> String {
    if name.starts_with("procedural") {
        return "procedural".to_owned();
    }
    match name.find("-res") {
        Some(i) => name[..i].to_owned(),
        None => name.to_owned(),
    }
}

/// One labelled frame: a view of a scene at one budget.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameInfo {
    /// Frame id (the values of `frame.npy`).
    pub id: u32,
    /// Scene id.
    pub scene: u32,
    /// View index on the orbit.
    pub view: u32,
    /// Budget share.
    pub budget_share: f64,
    /// `M`, fragments.
    pub budget: u64,
    /// `N`, fragments of the frame.
    pub fragments: u64,
    /// `C`, covered pixels.
    pub covered: u64,
    /// `Σ k_opt` over the whole frame (= `min(M, N)`).
    pub sum_k: u64,
    /// Rows the frame contributed.
    pub rows: u64,
}

/// A dataset in memory: rows of features and labels, and what they came from.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Dataset {
    /// What was rendered.
    pub spec: DatasetSpec,
    /// Features, `[rows, FEATURE_COUNT]` row-major.
    pub features: Vec<f32>,
    /// Labels, `[rows, LABELS.len()]` row-major.
    pub labels: Vec<f32>,
    /// Frame id of each row.
    pub frame: Vec<u32>,
    /// Scene id of each row.
    pub scene: Vec<u32>,
    /// Pixel index of each row.
    pub pixel: Vec<u32>,
    /// The scenes.
    pub scenes: Vec<SceneInfo>,
    /// The frames.
    pub frames: Vec<FrameInfo>,
}

/// The camera of view `view` of `views`: `camera` turned about its up axis through its target by
/// `360° · view / views`.
pub fn orbit_camera(camera: &Camera, view: u32, views: u32) -> Camera {
    let up = camera.up.try_normalize().unwrap_or(Vec3::Y);
    let angle = std::f32::consts::TAU * view as f32 / views.max(1) as f32;
    let turn = Mat3::from_axis_angle(up, angle);
    Camera {
        eye: camera.target + turn * (camera.eye - camera.target),
        ..*camera
    }
}

/// Rows per frame before sampling, and the kept pixels after.
fn sample(counts: &[u32], cap: Option<usize>, seed: u64, frame: u32) -> Vec<u32> {
    let covered: Vec<u32> = (0..counts.len() as u32)
        .filter(|&p| counts[p as usize] > 0)
        .collect();
    let Some(cap) = cap.filter(|&c| c < covered.len()) else {
        return covered;
    };
    let salt = mix(seed ^ mix(u64::from(frame) ^ 0x4652_414D_4553));
    let mut keys: Vec<(u64, u32)> = covered
        .iter()
        .map(|&p| (mix(salt ^ u64::from(p)), p))
        .collect();
    if cap == 0 {
        return Vec::new();
    }
    keys.select_nth_unstable(cap - 1);
    let mut kept: Vec<u32> = keys[..cap].iter().map(|&(_, p)| p).collect();
    kept.sort_unstable();
    kept
}

/// The label row of a pixel with `count` fragments and oracle `k` in a frame of `total`.
fn labels(count: u32, k: u32, total: u64, curve: &[f32; CURVE_LEN]) -> [f32; LABELS.len()] {
    let kept = if count >= 2 {
        k.saturating_sub(1) as f32 / (count - 1) as f32
    } else {
        k as f32
    };
    let mut out = [0.0; LABELS.len()];
    out[..3].copy_from_slice(&[k as f32, kept, k as f32 / total.max(1) as f32]);
    out[3..].copy_from_slice(curve);
    out
}

/// The truncation-error curve of pixel `p` of the sorted `regions` on `background`:
/// `e(k) = ‖C(k) − C(all)‖` for `k = 1 … CURVE_LEN` (0 once `k` reaches the pixel's count).
fn error_curve(regions: &Regions, p: usize, background: [f32; 3]) -> [f32; CURVE_LEN] {
    let run = regions.stored(p);
    let colour =
        |k: usize| composite::over_front_to_back(run[..k].iter().map(|f| f.color), background);
    let full = colour(run.len());
    std::array::from_fn(|i| {
        let k = i + 1;
        if k >= run.len() {
            return 0.0;
        }
        let c = colour(k);
        ((c[0] - full[0]).powi(2) + (c[1] - full[1]).powi(2) + (c[2] - full[2]).powi(2)).sqrt()
    })
}

/// Reused buffers of the labelling passes.
#[derive(Debug, Default)]
struct Buffers {
    raster: Rasterizer,
    counts: FragmentCounts,
    sums: FeatureAccumulator,
    regions: Regions,
    maps: FeatureMaps,
    k: Vec<u32>,
}

impl Dataset {
    /// An empty dataset for `spec`, checking it.
    pub fn new(spec: DatasetSpec) -> Result<Self, DatasetError> {
        if spec.views == 0 {
            return Err(DatasetError::NoViews);
        }
        if let Some(b) = spec.budgets.iter().find(|b| !(**b > 0.0 && **b <= 1.0)) {
            return Err(DatasetError::BadBudget(format!("{}", b * 100.0)));
        }
        Ok(Dataset {
            spec,
            ..Dataset::default()
        })
    }

    /// Rows so far.
    pub fn rows(&self) -> usize {
        self.frame.len()
    }

    /// Adds every view of `scene` at every budget; `progress` hears about each finished frame.
    pub fn add_scene(
        &mut self,
        scene: &Scene,
        mut progress: impl FnMut(&FrameInfo),
    ) -> Result<(), DatasetError> {
        let id = self.scenes.len() as u32;
        self.scenes.push(SceneInfo {
            id,
            name: scene.name.clone(),
            family: family_of(&scene.name),
            size: (scene.width, scene.height),
        });
        let mut buf = Buffers::default();
        for view in 0..self.spec.views {
            let camera = orbit_camera(&scene.camera, view, self.spec.views);
            let mut input = FrameInput::from_scene(scene, 0);
            input.view = camera.view();
            input.projection = camera.projection(scene.width, scene.height);
            self.add_view(&mut buf, &input, id, view, &mut progress)?;
        }
        Ok(())
    }

    /// Rasterizes one view and labels it at every budget.
    fn add_view(
        &mut self,
        buf: &mut Buffers,
        input: &FrameInput<'_>,
        scene: u32,
        view: u32,
        progress: &mut impl FnMut(&FrameInfo),
    ) -> Result<(), DatasetError> {
        let (w, h) = (input.width, input.height);
        buf.counts.clear(w, h)?;
        buf.sums.clear(w, h)?;
        let prepared = buf.raster.prepare(input);
        let total = prepared
            .rasterize(&mut FeatureCapture {
                counts: &mut buf.counts,
                sums: &mut buf.sums,
            })
            .fragments;
        buf.regions.with_capacities(w, h, buf.counts.counts())?;
        prepared.rasterize(&mut RegionCapture::new(
            &mut buf.regions,
            Policy::Append,
            None,
        ));
        buf.regions.sort_runs();
        for b in self.spec.budgets.clone() {
            let budget = (total as f64 * b).floor() as u64;
            let frame = self.frames.len() as u32;
            buf.k = optimal_k(&buf.regions, input.background, budget);
            let stats = buf
                .maps
                .compute(&buf.sums, buf.counts.counts(), budget, input.background);
            let counts = buf.counts.counts();
            let kept = sample(counts, self.spec.pixels_per_frame, self.spec.seed, frame);
            for &p in &kept {
                let i = p as usize;
                self.features.extend_from_slice(&buf.maps.pixel(i));
                let curve = error_curve(&buf.regions, i, input.background);
                self.labels
                    .extend_from_slice(&labels(counts[i], buf.k[i], total, &curve));
            }
            self.frame.extend(std::iter::repeat_n(frame, kept.len()));
            self.scene.extend(std::iter::repeat_n(scene, kept.len()));
            self.pixel.extend_from_slice(&kept);
            let info = FrameInfo {
                id: frame,
                scene,
                view,
                budget_share: b,
                budget,
                fragments: total,
                covered: stats.covered,
                sum_k: buf.k.par_iter().map(|&k| u64::from(k)).sum(),
                rows: kept.len() as u64,
            };
            progress(&info);
            self.frames.push(info);
        }
        Ok(())
    }

    /// Writes the arrays and `manifest.json` into `dir` (created if missing); see the module docs.
    pub fn write(&self, dir: &Path) -> Result<serde_json::Value, DatasetError> {
        std::fs::create_dir_all(dir).map_err(|source| DatasetError::Io {
            path: dir.to_owned(),
            source,
        })?;
        let n = self.rows();
        let arrays: [(&str, Vec<usize>, NpyData<'_>); 5] = [
            (
                "features.npy",
                vec![n, FEATURE_COUNT],
                NpyData::F32(&self.features),
            ),
            (
                "labels.npy",
                vec![n, LABELS.len()],
                NpyData::F32(&self.labels),
            ),
            ("frame.npy", vec![n], NpyData::U32(&self.frame)),
            ("scene.npy", vec![n], NpyData::U32(&self.scene)),
            ("pixel.npy", vec![n], NpyData::U32(&self.pixel)),
        ];
        let mut files = serde_json::Map::new();
        for (name, shape, data) in arrays {
            let bytes = npy::encode(&shape, data);
            let path = dir.join(name);
            std::fs::write(&path, &bytes).map_err(|source| DatasetError::Io { path, source })?;
            let dtype = match data {
                NpyData::F32(_) => "float32",
                NpyData::U32(_) => "uint32",
            };
            files.insert(
                name.to_owned(),
                serde_json::json!({"shape": shape, "dtype": dtype, "fnv1a64": fnv1a64_hex(&bytes)}),
            );
        }
        let manifest = self.manifest(files);
        let path = dir.join("manifest.json");
        let text = serde_json::to_string_pretty(&manifest).unwrap_or_default() + "\n";
        std::fs::write(&path, text).map_err(|source| DatasetError::Io { path, source })?;
        Ok(manifest)
    }

    fn manifest(&self, files: serde_json::Map<String, serde_json::Value>) -> serde_json::Value {
        let scenes: Vec<_> = self
            .scenes
            .iter()
            .map(|s| {
                serde_json::json!({"id": s.id, "name": s.name, "family": s.family,
                    "width": s.size.0, "height": s.size.1})
            })
            .collect();
        let frames: Vec<_> = self
            .frames
            .iter()
            .map(|f| {
                serde_json::json!({"id": f.id, "scene": f.scene, "view": f.view,
                    "budget_share": f.budget_share, "budget": f.budget, "fragments": f.fragments,
                    "covered": f.covered, "sum_k": f.sum_k, "rows": f.rows})
            })
            .collect();
        serde_json::json!({
            "format": DATASET_FORMAT,
            "feature_set": FEATURE_SET,
            "features": feature_names(),
            "labels": LABELS,
            "seed": self.spec.seed,
            "views": self.spec.views,
            "budgets": self.spec.budgets,
            "pixels_per_frame": self.spec.pixels_per_frame,
            "rows": self.rows(),
            "scenes": scenes,
            "frames": frames,
            "files": files,
        })
    }
}

/// FNV-1a 64 of `bytes` as 16 hex digits: a change detector for the manifest, not a
/// cryptographic hash.
pub fn fnv1a64_hex(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budgets_parse_and_refuse() {
        assert_eq!(parse_budget("50").unwrap(), 0.5);
        assert_eq!(parse_budget(" 85% ").unwrap(), 0.85);
        assert_eq!(parse_budget("100").unwrap(), 1.0);
        for bad in ["0", "-5", "101", "half", ""] {
            let e = parse_budget(bad).unwrap_err();
            assert!(matches!(e, DatasetError::BadBudget(_)), "{bad}");
            assert!(e.to_string().contains("above 0 % and up to 100 %"));
        }
    }

    #[test]
    fn families_and_labels() {
        assert_eq!(family_of("dragon-res2"), "dragon");
        assert_eq!(family_of("dragon"), "dragon");
        assert_eq!(family_of("procedural-7"), "procedural");
        let curve = [0.5, 0.25, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(labels(5, 3, 100, &curve)[..3], [3.0, 0.5, 0.03]);
        assert_eq!(labels(5, 3, 100, &curve)[3..], curve);
        assert_eq!(labels(1, 1, 10, &curve)[..3], [1.0, 1.0, 0.1]);
        assert_eq!(labels(4, 0, 10, &curve)[1], 0.0);
    }

    #[test]
    fn sampling_is_seeded_and_capped() {
        let counts: Vec<u32> = (0..1000).map(|p| p % 3).collect();
        let all = sample(&counts, None, 1, 0);
        assert_eq!(all.len(), 666);
        let a = sample(&counts, Some(100), 1, 0);
        assert_eq!(a, sample(&counts, Some(100), 1, 0));
        assert_eq!(a.len(), 100);
        assert!(a.windows(2).all(|w| w[0] < w[1]));
        assert!(a.iter().all(|&p| counts[p as usize] > 0));
        assert_ne!(a, sample(&counts, Some(100), 2, 0));
        assert_ne!(a, sample(&counts, Some(100), 1, 1));
        assert_eq!(sample(&counts, Some(5000), 1, 0), all);
    }

    #[test]
    fn fnv_reference_values() {
        // Published FNV-1a 64 test vectors.
        assert_eq!(fnv1a64_hex(b""), "cbf29ce484222325");
        assert_eq!(fnv1a64_hex(b"a"), "af63dc4c8601ec8c");
    }
}
