//! Deep operations as pure functions: sort, merge, flatten and sample statistics.
//!
//! They follow "Interpreting OpenEXR Deep Pixels" and match OpenImageIO's `--deepmerge` and
//! `--flatten` (OIIO 2.4 to 3.1), so that strata and `oiiotool` produce the same pictures:
//!
//! - channel roles are found as OIIO finds them: `Z`, `ZBack`, `A` (or `Alpha`), `AR`/`AG`/`AB`,
//!   each also as the last component of a dotted name (`diffuse.A`); a colour channel is
//!   premultiplied by the alpha of its layer (`AR` for `R` when present, else `A`). `UINT`
//!   channels (object ids) are never scaled or blended: a split sample keeps its id, and two
//!   samples merged into one keep the front one's id.
//! - [`sort`]: per pixel, a stable sort by `Z`, then `ZBack`.
//! - [`merge`]: images are merged pairwise, left to right, as `A B --deepmerge C --deepmerge …`:
//!   per pixel the samples are concatenated and sorted by `Z`, every volumetric sample (`Z < ZBack`) is
//!   split at every other sample's `Z` and `ZBack` (colour and alpha divided with the
//!   exponential-absorption formulas), samples covering exactly the same depth range are
//!   combined, and everything behind the first opaque (`A ≥ 1`) sample is dropped. A pixel only
//!   one image covers is copied unchanged. Like every released OpenImageIO (2.4 to 3.1), the
//!   merge orders by `Z` alone and keeps samples at equal `Z` in the order they arrived (earlier
//!   image first, a split sample's front part before its back part); OIIO's development branch
//!   (mid-2026) also orders them by `ZBack`, as [`sort`] does. The two agree unless samples start
//!   at the same `Z` with different `ZBack`, which point samples (strata's) never do.
//! - [`flatten`]: front-to-back OVER of the samples in stored order, stopping once the
//!   accumulated alpha reaches 1; `Z`/`ZBack` accumulate as OIIO does, and are 1e30 in empty pixels.

use crate::error::{ExrError, Result};
use crate::image::{Box2i, Channel, Column, DeepImage, FlatImage, SampleType};

/// The largest data window a merge produces (the union of its inputs' windows).
const MAX_MERGED_PIXELS: u64 = 1 << 28; // = Limits::default().max_pixels: what merges can be read back

/// `Z`/`ZBack` of a pixel without samples after flattening (OIIO's value).
const EMPTY_DEPTH: f32 = 1.0e30;

fn is_or_ends_with_dot(name: &str, suffix: &str) -> bool {
    if name.eq_ignore_ascii_case(suffix) {
        return true;
    }
    let (n, s) = (name.as_bytes(), suffix.as_bytes());
    n.len() > s.len()
        && n[n.len() - s.len()..].eq_ignore_ascii_case(s)
        && n[n.len() - s.len() - 1] == b'.'
}

/// Which channel plays which part, and each channel's alpha.
#[derive(Clone, Debug)]
struct Roles {
    z: Option<usize>,
    zback: Option<usize>,
    alpha: Option<usize>,
    ar: Option<usize>,
    ag: Option<usize>,
    ab: Option<usize>,
    /// For each channel: the alpha channel it is premultiplied by (itself for alphas), or none.
    alpha_of: Vec<Option<usize>>,
    /// For each channel: stored as `HALF`, so computed values are rounded to half precision (as
    /// OIIO, which keeps deep values in their file types, does).
    half: Vec<bool>,
}

impl Roles {
    fn new(channels: &[Channel]) -> Self {
        let find = |names: &[&str], skip: &[Option<usize>]| {
            channels.iter().enumerate().position(|(i, c)| {
                !skip.contains(&Some(i)) && names.iter().any(|n| is_or_ends_with_dot(&c.name, n))
            })
        };
        let z = find(&["Z"], &[]);
        let zback = find(&["ZBack"], &[z]);
        let alpha = find(&["A", "Alpha"], &[z, zback]);
        let ar = find(&["AR"], &[]);
        let ag = find(&["AG"], &[]);
        let ab = find(&["AB"], &[]);
        let alpha_of = channels
            .iter()
            .enumerate()
            .map(|(i, c)| {
                if Some(i) == z || Some(i) == zback || c.sample_type == SampleType::Uint {
                    return None;
                }
                if ["A", "AR", "AG", "AB", "Alpha"]
                    .iter()
                    .any(|n| is_or_ends_with_dot(&c.name, n))
                {
                    return Some(i);
                }
                let (prefix, suffix) = match c.name.rfind('.') {
                    Some(dot) => (&c.name[..=dot], &c.name[dot + 1..]),
                    None => ("", c.name.as_str()),
                };
                let target = format!("{prefix}A{suffix}");
                channels
                    .iter()
                    .position(|o| o.name.eq_ignore_ascii_case(&target))
                    .or(alpha)
            })
            .collect();
        Roles {
            z,
            zback,
            alpha,
            ar,
            ag,
            ab,
            alpha_of,
            half: channels
                .iter()
                .map(|c| c.sample_type == SampleType::Half)
                .collect(),
        }
    }
}

/// One pixel's samples as rows of channel values (float bits or integers), reused across pixels.
#[derive(Clone, Debug, Default)]
struct Pixel {
    stride: usize,
    data: Vec<u32>,
}

impl Pixel {
    fn len(&self) -> usize {
        self.data.len() / self.stride
    }

    fn f(&self, s: usize, c: usize) -> f32 {
        f32::from_bits(self.data[s * self.stride + c])
    }

    fn set_f(&mut self, s: usize, c: usize, v: f32) {
        self.data[s * self.stride + c] = v.to_bits();
    }

    /// Sets a computed value, rounded to the channel's stored precision.
    fn set_value(&mut self, roles: &Roles, s: usize, c: usize, v: f32) {
        let v = if roles.half[c] {
            half::f16::from_f32(v).to_f32()
        } else {
            v
        };
        self.set_f(s, c, v);
    }

    fn row(&self, s: usize) -> &[u32] {
        &self.data[s * self.stride..(s + 1) * self.stride]
    }

    fn load(&mut self, image: &DeepImage, range: std::ops::Range<usize>) {
        self.stride = image.columns.len();
        self.data.clear();
        for s in range {
            self.push_sample(image, s);
        }
    }

    fn push_sample(&mut self, image: &DeepImage, s: usize) {
        for col in &image.columns {
            self.data.push(match col {
                Column::F32(v) => v[s].to_bits(),
                Column::U32(v) => v[s],
            });
        }
    }

    fn store(&self, columns: &mut [Column]) {
        for s in 0..self.len() {
            for (c, col) in columns.iter_mut().enumerate() {
                let bits = self.data[s * self.stride + c];
                match col {
                    Column::F32(v) => v.push(f32::from_bits(bits)),
                    Column::U32(v) => v.push(bits),
                }
            }
        }
    }

    /// A stable sort by `Z`, then (if `by_zback`) `ZBack`; NaN last so the order stays total.
    fn sort(&mut self, roles: &Roles, by_zback: bool) {
        let Some(z) = roles.z else { return };
        let zb = if by_zback {
            roles.zback.unwrap_or(z)
        } else {
            z
        };
        if self.len() < 2 {
            return;
        }
        let key = |r: &[u32]| (f32::from_bits(r[z]), f32::from_bits(r[zb]));
        let mut rows: Vec<&[u32]> = self.data.chunks_exact(self.stride).collect();
        rows.sort_by(|a, b| {
            let (az, azb) = key(a);
            let (bz, bzb) = key(b);
            cmp_nan_last(az, bz).then(cmp_nan_last(azb, bzb))
        });
        self.data = rows.concat();
    }
}

fn cmp_nan_last(a: f32, b: f32) -> std::cmp::Ordering {
    match (a.is_nan(), b.is_nan()) {
        (false, false) => a.partial_cmp(&b).unwrap_or(std::cmp::Ordering::Equal),
        (true, true) => std::cmp::Ordering::Equal,
        (true, false) => std::cmp::Ordering::Greater,
        (false, true) => std::cmp::Ordering::Less,
    }
}

/// The image with every pixel's samples sorted front to back by `Z`, then `ZBack` (stable).
/// Without a `Z` channel the image is returned unchanged.
pub fn sort(image: &DeepImage) -> DeepImage {
    let roles = Roles::new(&image.channels);
    let mut out = empty_like(image, image.data_window, image.sample_count());
    let mut pixel = Pixel::default();
    for p in 0..image.offsets.len() - 1 {
        pixel.load(image, image.pixel_range(p));
        pixel.sort(&roles, true);
        pixel.store(&mut out.columns);
        out.offsets.push(out.columns[0].len() as u32);
    }
    out
}

fn empty_like(image: &DeepImage, window: Box2i, capacity: usize) -> DeepImage {
    let pixels = window.pixel_count() as usize;
    let mut offsets = Vec::with_capacity(pixels + 1);
    offsets.push(0);
    DeepImage {
        data_window: window,
        display_window: image.display_window,
        channels: image.channels.clone(),
        offsets,
        columns: image
            .channels
            .iter()
            .map(|c| Column::with_capacity(c.sample_type, capacity))
            .collect(),
        attributes: image.attributes.clone(),
    }
}

/// Merges deep images as `oiiotool A B --deepmerge C --deepmerge …` does (see the module docs).
///
/// The images must have the same channel names, and a channel must be `UINT` in all of them or
/// in none; a channel stored as `HALF` in one and `FLOAT` in another is `FLOAT` in the result. The
/// result covers the union of the data windows (and of the display windows); its other
/// attributes are the first image's.
///
/// # Errors
/// [`ExrError::Mismatch`] if there is no image, the channels differ or the union of the data
/// windows exceeds 2^28 pixels;
/// [`ExrError::InvalidImage`] if the result would exceed 2^32 − 1 samples.
pub fn merge(images: &[DeepImage]) -> Result<DeepImage> {
    let first = images
        .first()
        .ok_or_else(|| ExrError::Mismatch("no image to merge".into()))?;
    let channels = merged_channels(images)?;
    let window = images
        .iter()
        .fold(first.data_window, |w, i| w.union(&i.data_window));
    if window.pixel_count() > MAX_MERGED_PIXELS {
        return Err(ExrError::Mismatch(format!(
            "the data windows are far apart: together they span {} pixels (at most {MAX_MERGED_PIXELS})",
            window.pixel_count()
        )));
    }
    let display = images
        .iter()
        .fold(first.display_window, |w, i| w.union(&i.display_window));
    let roles = Roles::new(&channels);
    let capacity: usize = images.iter().map(DeepImage::sample_count).sum();
    let mut out = empty_like(first, window, capacity);
    out.channels = channels;
    out.display_window = display;
    let mut work = MergeScratch::default();
    for y in i64::from(window.y_min)..=i64::from(window.y_max) {
        for x in i64::from(window.x_min)..=i64::from(window.x_max) {
            merge_one_pixel(images, &roles, x, y, &mut work)?;
            let dst = &work.dst;
            dst.store(&mut out.columns);
            let total = u32::try_from(out.columns[0].len()).map_err(|_| {
                ExrError::InvalidImage("the merged image holds over 2^32 - 1 samples".into())
            })?;
            out.offsets.push(total);
        }
    }
    Ok(out)
}

/// Buffers one pixel's merge reuses from pixel to pixel.
#[derive(Default)]
struct MergeScratch {
    dst: Pixel,
    src: Pixel,
    pieces: Pixel,
    bounds: Vec<f32>,
}

/// Most samples one pixel may hold after overlapping volumetric samples are split: `n` samples
/// that all overlap split into up to `n · 2n` pieces, so a small hostile file could otherwise ask
/// for unbounded work.
pub const MAX_SPLIT_SAMPLES_PER_PIXEL: usize = 1 << 16;

fn merge_one_pixel(
    images: &[DeepImage],
    roles: &Roles,
    x: i64,
    y: i64,
    work: &mut MergeScratch,
) -> Result<()> {
    let dst = &mut work.dst;
    dst.stride = images[0].columns.len();
    dst.data.clear();
    if let Some(range) = images[0].pixel_at(x, y) {
        dst.load(&images[0], range);
    }
    // Every input's samples in depth order, even where only one image covers the pixel.
    dst.sort(roles, false);
    for image in &images[1..] {
        let Some(range) = image.pixel_at(x, y) else {
            continue;
        };
        work.src.load(image, range);
        merge_pixels(work, roles).map_err(|n| {
            ExrError::InvalidImage(format!(
                "pixel ({x},{y}): splitting its overlapping volumetric samples would make {n} \
                 samples (at most {MAX_SPLIT_SAMPLES_PER_PIXEL})"
            ))
        })?;
        occlusion_cull(&mut work.dst, roles);
    }
    Ok(())
}

fn merged_channels(images: &[DeepImage]) -> Result<Vec<Channel>> {
    let mut channels = images[0].channels.clone();
    for (i, image) in images.iter().enumerate().skip(1) {
        let names = |cs: &[Channel]| cs.iter().map(|c| c.name.clone()).collect::<Vec<_>>();
        if names(&image.channels) != names(&channels) {
            return Err(ExrError::Mismatch(format!(
                "image {} has channels {:?}, image 1 has {:?}",
                i + 1,
                names(&image.channels),
                names(&channels)
            )));
        }
        for (mine, theirs) in channels.iter_mut().zip(&image.channels) {
            let uint = |c: &Channel| c.sample_type == SampleType::Uint;
            if uint(mine) != uint(theirs) {
                return Err(ExrError::Mismatch(format!(
                    "channel `{}` is {} in image 1 and {} in image {}",
                    mine.name,
                    mine.sample_type.name(),
                    theirs.sample_type.name(),
                    i + 1
                )));
            }
            if theirs.sample_type == SampleType::Float {
                mine.sample_type = SampleType::Float;
            }
        }
    }
    Ok(channels)
}

/// OIIO's `DeepData::merge_deep_pixels`: `src` joins `dst`, sorted by `Z`; every volumetric
/// sample is split at every sample boundary inside it; samples covering the same range combine.
/// Linear in the pieces made (OIIO inserts and erases rows one at a time). Fails with the number
/// of pieces if they would exceed [`MAX_SPLIT_SAMPLES_PER_PIXEL`].
fn merge_pixels(work: &mut MergeScratch, roles: &Roles) -> std::result::Result<(), usize> {
    let MergeScratch {
        dst,
        src,
        pieces,
        bounds,
    } = work;
    if src.len() == 0 {
        return Ok(());
    }
    let was_empty = dst.len() == 0;
    dst.data.extend_from_slice(&src.data);
    dst.sort(roles, false);
    if was_empty {
        // As OIIO: the first samples a pixel gets are taken as they are (sorted here).
        return Ok(());
    }
    if let (Some(z), Some(zb)) = (roles.z, roles.zback) {
        split_at_boundaries(dst, pieces, bounds, roles, z, zb)?;
        dst.sort(roles, false);
    }
    merge_overlaps(dst, pieces, roles);
    Ok(())
}

/// Splits every volumetric sample (`Z < ZBack`) at every `Z` or `ZBack` of the pixel that lies
/// strictly inside it, as OIIO's repeated `DeepData::split` does. A piece spanning the fraction
/// `x` of its sample's depth range gets alpha `1 − (1 − a)^x` and colour `v · alpha_piece / a`
/// (`v · x` for a sample with no alpha; an opaque channel keeps its value) — what splitting the
/// pieces one after another gives, since `(1 − a)^x` multiplies across pieces.
fn split_at_boundaries(
    px: &mut Pixel,
    pieces: &mut Pixel,
    bounds: &mut Vec<f32>,
    roles: &Roles,
    z: usize,
    zb: usize,
) -> std::result::Result<(), usize> {
    bounds.clear();
    for s in 0..px.len() {
        bounds.extend(
            [px.f(s, z), px.f(s, zb)]
                .into_iter()
                .filter(|v| !v.is_nan()),
        );
    }
    bounds.sort_by(|a, b| a.total_cmp(b));
    bounds.dedup();
    pieces.stride = px.stride;
    pieces.data.clear();
    for s in 0..px.len() {
        let (front, back) = (px.f(s, z), px.f(s, zb));
        let inside = if front < back {
            let lo = bounds.partition_point(|&b| b <= front);
            let hi = bounds.partition_point(|&b| b < back);
            &bounds[lo..hi.max(lo)]
        } else {
            &[][..]
        };
        if pieces.len() + inside.len() + 1 > MAX_SPLIT_SAMPLES_PER_PIXEL {
            return Err(pieces.len() + inside.len() + 1);
        }
        if inside.is_empty() {
            pieces.data.extend_from_slice(px.row(s));
            continue;
        }
        let span = back - front;
        let mut start = front;
        for &end in inside.iter().chain(std::iter::once(&back)) {
            let at = pieces.len();
            pieces.data.extend_from_slice(px.row(s));
            pieces.set_value(roles, at, z, start);
            pieces.set_value(roles, at, zb, end);
            let x = (end - start) / span;
            for c in 0..px.stride {
                let Some(ac) = roles.alpha_of[c] else {
                    continue;
                };
                let a = px.f(s, ac).clamp(0.0, 1.0);
                if a == 1.0 {
                    continue;
                }
                let v = px.f(s, c);
                let piece = if a > f32::MIN_POSITIVE {
                    let a_piece = -(x * (-a).ln_1p()).exp_m1();
                    if ac == c { a_piece } else { (a_piece / a) * v }
                } else {
                    v * x
                };
                pieces.set_value(roles, at, c, piece);
            }
            start = end;
        }
    }
    std::mem::swap(&mut px.data, &mut pieces.data);
    Ok(())
}

/// Combines consecutive samples covering exactly the same depth range (OIIO's
/// `DeepData::merge_overlaps`), in one pass: each sample either starts a new row of `out` or is
/// combined into its last row.
fn merge_overlaps(px: &mut Pixel, out: &mut Pixel, roles: &Roles) {
    let Some(z) = roles.z else { return };
    let zb = roles.zback.unwrap_or(z);
    out.stride = px.stride;
    out.data.clear();
    for s in 0..px.len() {
        let last = out.len().checked_sub(1);
        let same = last.is_some_and(|l| out.f(l, z) == px.f(s, z) && out.f(l, zb) == px.f(s, zb));
        let Some(l) = last.filter(|_| same) else {
            out.data.extend_from_slice(px.row(s));
            continue;
        };
        // Colours first: they read both alphas before the combined alpha is written.
        for pass_alpha in [false, true] {
            for c in 0..px.stride {
                let Some(ac) = roles.alpha_of[c] else {
                    continue;
                };
                if (ac == c) != pass_alpha {
                    continue;
                }
                let a1 = out.f(l, ac).clamp(0.0, 1.0);
                let a2 = px.f(s, ac).clamp(0.0, 1.0);
                let am = a1 + a2 - a1 * a2;
                let merged = if pass_alpha {
                    am
                } else {
                    merged_colour(out.f(l, c), px.f(s, c), a1, a2, am)
                };
                out.set_value(roles, l, c, merged);
            }
        }
    }
    std::mem::swap(&mut px.data, &mut out.data);
}

fn merged_colour(c1: f32, c2: f32, a1: f32, a2: f32, am: f32) -> f32 {
    if a1 == 1.0 && a2 == 1.0 {
        return (c1 + c2) / 2.0;
    }
    if a1 == 1.0 {
        return c1;
    }
    if a2 == 1.0 {
        return c2;
    }
    let u1 = -(-a1).ln_1p();
    let v1 = if u1 < a1 * f32::MAX { u1 / a1 } else { 1.0 };
    let u2 = -(-a2).ln_1p();
    let v2 = if u2 < a2 * f32::MAX { u2 / a2 } else { 1.0 };
    let u = u1 + u2;
    let w = if u > 1.0 || am < u * f32::MAX {
        am / u
    } else {
        1.0
    };
    (c1 * v1 + c2 * v2) * w
}

/// Drops every sample behind the first one with `A ≥ 1`.
fn occlusion_cull(px: &mut Pixel, roles: &Roles) {
    let Some(a) = roles.alpha else { return };
    if let Some(s) = (0..px.len()).find(|&s| px.f(s, a) >= 1.0) {
        px.data.truncate((s + 1) * px.stride);
    }
}

/// Composites every pixel's samples front to back (in stored order: [`sort`] first if they may
/// not be sorted) into a flat image, as `oiiotool --flatten` does.
///
/// The result has the deep image's float channels with their types; `UINT` channels (ids) have
/// no flat meaning and are dropped.
///
/// # Errors
/// [`ExrError::InvalidImage`] if the image has no alpha channel (`A`, or `AR`/`AG`/`AB`).
pub fn flatten(image: &DeepImage) -> Result<FlatImage> {
    let roles = Roles::new(&image.channels);
    let alpha = |specific: Option<usize>| specific.or(roles.alpha);
    let (Some(ar), Some(ag), Some(ab)) = (alpha(roles.ar), alpha(roles.ag), alpha(roles.ab)) else {
        return Err(ExrError::InvalidImage(
            "the deep image has no alpha channel (A) to composite with".into(),
        ));
    };
    let kept: Vec<usize> = (0..image.channels.len())
        .filter(|&c| image.channels[c].sample_type != SampleType::Uint)
        .collect();
    let weight_of: Vec<usize> = (0..image.channels.len())
        .map(|c| match image.channels[c].name.as_str() {
            "R" => ar,
            "G" => ag,
            "B" => ab,
            _ => usize::MAX,
        })
        .collect();
    let pixels = image.offsets.len() - 1;
    let mut columns: Vec<Vec<f32>> = kept.iter().map(|_| Vec::with_capacity(pixels)).collect();
    let mut acc = vec![0f32; image.channels.len()];
    for p in 0..pixels {
        flatten_pixel(image, &roles, [ar, ag, ab], &weight_of, p, &mut acc);
        for (out, &c) in columns.iter_mut().zip(&kept) {
            out.push(acc[c]);
        }
    }
    let mut flat = FlatImage::new(
        image.data_window,
        kept.iter().map(|&c| image.channels[c].clone()).collect(),
        columns.into_iter().map(Column::F32).collect(),
    )?;
    flat.display_window = image.display_window;
    Ok(flat)
}

fn flatten_pixel(
    image: &DeepImage,
    roles: &Roles,
    [ar, ag, ab]: [usize; 3],
    weight_of: &[usize],
    p: usize,
    acc: &mut [f32],
) {
    acc.fill(0.0);
    let range = image.pixel_range(p);
    for c in [roles.z, roles.zback].into_iter().flatten() {
        if range.is_empty() {
            acc[c] = EMPTY_DEPTH;
        }
    }
    for s in range {
        let (a_r, a_g, a_b) = (acc[ar], acc[ag], acc[ab]);
        let alpha = (a_r + a_g + a_b) / 3.0;
        if alpha >= 1.0 {
            break;
        }
        for (c, col) in image.columns.iter().enumerate() {
            let Column::F32(values) = col else { continue };
            if Some(c) == roles.z || Some(c) == roles.zback {
                acc[c] *= alpha;
            }
            let a = match weight_of[c] {
                w if w == ar => a_r,
                w if w == ag => a_g,
                w if w == ab => a_b,
                _ => alpha,
            };
            acc[c] += (1.0 - a) * values[s];
        }
    }
}

/// Sample statistics of a deep image (for `inspect`).
#[derive(Clone, Debug, PartialEq)]
pub struct DeepStats {
    /// Pixels in the data window.
    pub pixels: u64,
    /// Total samples.
    pub samples: u64,
    /// Pixels without a sample.
    pub empty_pixels: u64,
    /// The fewest samples in one pixel.
    pub min_per_pixel: u32,
    /// The most samples in one pixel.
    pub max_per_pixel: u32,
    /// A pixel holding `max_per_pixel` samples (absolute coordinates).
    pub max_at: (i64, i64),
    /// Mean samples per pixel.
    pub mean_per_pixel: f64,
    /// Pixel counts by samples per pixel: entry `i` counts pixels with `0` samples for `i = 0`,
    /// and with `2^(i-1) ..= 2^i - 1` samples for `i ≥ 1` (1, 2–3, 4–7, …).
    pub histogram: Vec<u64>,
}

/// Counts samples per pixel.
pub fn stats(image: &DeepImage) -> DeepStats {
    let pixels = (image.offsets.len() - 1) as u64;
    let mut histogram = vec![0u64; 34];
    let (mut min, mut max, mut max_p) = (u32::MAX, 0u32, 0usize);
    for (p, w) in image.offsets.windows(2).enumerate() {
        let n = w[1] - w[0];
        histogram[(32 - n.leading_zeros()) as usize] += 1;
        min = min.min(n);
        if n > max {
            (max, max_p) = (n, p);
        }
    }
    while histogram.len() > 1 && histogram.last() == Some(&0) {
        histogram.pop();
    }
    let samples = image.sample_count() as u64;
    let w = image.width().max(1);
    DeepStats {
        pixels,
        samples,
        empty_pixels: histogram[0],
        min_per_pixel: if pixels == 0 { 0 } else { min },
        max_per_pixel: max,
        max_at: (
            i64::from(image.data_window.x_min) + (max_p % w) as i64,
            i64::from(image.data_window.y_min) + (max_p / w) as i64,
        ),
        mean_per_pixel: if pixels == 0 {
            0.0
        } else {
            samples as f64 / pixels as f64
        },
        histogram,
    }
}
