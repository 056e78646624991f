//! The memory and access model of Lin 2007 ch. 4, fed with our frames: the transparent-fragment
//! distribution (Table 4-1), the memory of R-buffer, WF and TFSS (Table 4-2, Figures 4-3 to 4-6),
//! the access-count / execution-time model (§4.3.2, Figure 4-7) — and, beside them, the layouts
//! strata uses and one that beats TFSS.
//!
//! Everything here is a pure function of plain data: a [`Distribution`] (pixels per number of
//! transparent fragments, what Table 4-1 prints) and, for leading-zeros elimination, a
//! [`ColourTrace`] (each pixel's colour lengths). Both come from a DeepFrame
//! ([`frame_model`]) or from the thesis's own table ([`Distribution::from_table`]).
//!
//! # Sizes ([`Sizes`])
//!
//! The thesis states the TFSS section (`L_num × 8` bytes: depth and RGBA, 4 bytes each), the state
//! memory (3 bits a pixel) and the bit width of the colour components (8); it does not state the
//! R-buffer fragment, the depth or the address size. strata takes
//!
//! | constant | value | why |
//! | --- | --- | --- |
//! | `S_f` R-buffer fragment | 12 B | x, y (2 B each: the R-buffer is a FIFO, it must store the location), z (4 B), RGBA (4 B) |
//! | fragment in WF / TFSS | 8 B | z (4 B) and RGBA (4 B); the pixel is implied by the section |
//! | `Z` | 4 B | a 32-bit depth; the second z-buffer is `W·H·Z` |
//! | state memory | 3 bit / pixel | as the thesis |
//! | `S_A` address | 4 B ([`Sizes::default`]) | 32-bit addresses: our 1280×720 frames need more than 2^16 sections |
//! | Length-table entry | 4 bit | lengths 0..=8 plus the empty/sealed codes (`lz::LengthCode`) |
//!
//! [`Sizes::seed_fit`] takes `S_A` = 2 B instead. The thesis's figures are not given as numbers, but
//! with 2-byte addresses its Table 4-1 frames give what its text quotes: TFSS(1) saves 41.2 %
//! against R-buffer on average (the top of Figure 4-4's 18–41 % range); over `L_num` 1–4 TFSS saves
//! 26.2 % against R-buffer and 66.6 % against WF (the conclusion: 29 % and 67 %); and frame480 at
//! `L_num` = 3 is the one frame where TFSS needs more than R-buffer, as §4.3.1 reports. With
//! 4-byte addresses the SSA table costs as much as the second z-buffer and TFSS would save only
//! 5.6 % at `L_num` 1 and lose from `L_num` 2 on, against Figure 4-3. (The tests check all of
//! this.)
//!
//! # Memory (Table 4-2)
//!
//! ```text
//! R-buffer   N_f·S_f  +  W·H·Z (2nd z-buffer)  +  ⌈3·W·H / 8⌉ (state memory)
//! WF         (W·H + N_A)·M_WF  +  S_A·(W·H + N_A)     M_WF = D_avg·8, N_A = Σ_p (⌈n_p/D_avg⌉ − 1)
//! TFSS       M_TFSS·N_S  +  S_A·W·H  +  S_A·N_S        M_TFSS = L_num·8,  N_S = Σ_p ⌈n_p/L_num⌉
//! ```
//!
//! `D_avg`, "the average number of fragments per pixel", is read over the transparent pixels (the
//! seed's "fragments per transparent pixel", Table 4-1) and rounded to the nearest integer (halves
//! up), at least 1: a section holds whole fragments. Rounding down instead lowers WF's memory
//! and the thesis's quoted 67 % saving of TFSS over WF is reproduced only with rounding to nearest.
//!
//! **With leading-zeros elimination** the thesis shrinks `M_section` and assumes the compressed
//! fragments fit (§4.3.1, Figure 4-5). Here the compressed sizes are measured: each fragment's
//! colour length `len` (`lz::rgb_length`) comes from the frame, a section of `L_num` slots holds
//! depths (32 bit each) plus a colour area of [`colour_area_bits`]`(L_num, b)` bits, and
//! fragments are packed into sections exactly as the store packs them — a record that does not fit
//! seals the section ([`packed_sections_of`]). For each `L_num` the budget `b` (bits per
//! component, 0..=8) with the least memory is reported as `TFSS(L_num, M_section)`, `M_section`
//! in bytes, plus the Length table (`⌈4·L_num / 8⌉` bytes a section). The thesis's lossy alpha
//! shift (`lz::alpha_shift`) is evaluated apart and labelled lossy; the store never applies it.
//!
//! Beside them ([`Layouts`]): strata's DeepFrame (`4·(W·H+1) + 12·N_f`), the S-buffer regions
//! (`4·(W·H+1) + 4·W·H + 12·N_f`), the linked list (`4·W·H + 16·N_f + 4`), strata's own TFSS
//! store (`4·W·H + (12·L_num + 4)·N_S + 4`, its sections hold the object id), and **compact
//! runs**, a layout that beats TFSS with the same 8-byte fragment: a per-pixel count (1 byte, 2
//! if a pixel holds more than 255), a 4-byte offset per 64 pixels, and every pixel's fragments
//! contiguous — no NSA table, no half-empty sections, and a count instead of a 4-byte address per
//! pixel. It needs the counts first (the S-buffer's counting pass, Tsopouridis 2021 Alg. 8), which is
//! what TFSS avoids. *Compact runs + LZ* stores each fragment as depth (32) + Length code (4) +
//! alpha (8) + `3·len` colour bits, bit-packed, with bit offsets per 64 pixels.
//!
//! # Time (§4.3.2)
//!
//! One cycle per memory access, with `N_i` the pixels holding `i` transparent fragments:
//!
//! ```text
//! R-buffer  f_R = Σ N_i·i(i+1)/2 (every pass re-reads what is left)   f_2nd-z = f_R
//!           f_frame = Σ N_i·i      computation Σ N_i·i(i+1)/2
//! WF        f_M = Σ N_i·i          computation Σ N_i·(i(i−1)/2 + 1)    (pointer memory in parallel)
//! TFSS      f_T = Σ N_i·i  + f_SSA = Σ_{i≥1} N_i   computation as WF  (NSA read with the section)
//! ```
//!
//! `f_SSA` counts one SSA read per pixel with transparent fragments. The read flow (Figure 3-9)
//! reads the SSA entry of every pixel, but counting all `W·H` reads would make TFSS slower than
//! R-buffer on every frame of Table 4-1, against Figure 4-7 ("just a little higher than WF"); an
//! SSA read that finds NULL is taken to overlap with the previous pixel's work. On Table 4-1 the
//! model gives TFSS 52.7 % less time than R-buffer on average (59.3 % on frame120, 39.0 % on
//! frame480); the thesis's conclusion quotes 45 %, and Figure 4-7's values are not in its text, so
//! the gap cannot be traced further. Beyond the thesis,
//! [`tfss_store_accesses`] counts the accesses of the *store* flow (Figure 3-8): per fragment one
//! SSA read, one NSA read per full section walked past, one T-buffer write, and one address write
//! per section allocated.

use strata_core::{DeepFrame, Rgba8};

use super::lz;

/// Bits of a packed record at full width (alpha + three 8-bit components).
const FULL_RECORD_BITS: u32 = 8 + 24;

/// Pixels per stored offset in the compact-runs layouts.
pub const COMPACT_OFFSET_EVERY: u64 = 64;

/// Pixels per number of transparent fragments: what Table 4-1 prints for a frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Distribution {
    /// Display width.
    pub width: u32,
    /// Display height.
    pub height: u32,
    /// All fragments of the frame, opaque and transparent (Table 4-1, column 2).
    pub fragments: u64,
    /// `histogram[i]`: pixels holding `i` transparent fragments (`histogram[0]`: none).
    pub histogram: Vec<u64>,
}

impl Distribution {
    /// From per-pixel transparent-fragment counts; `fragments` counts all fragments of the frame.
    pub fn from_counts(
        width: u32,
        height: u32,
        fragments: u64,
        counts: impl IntoIterator<Item = u32>,
    ) -> Self {
        let mut histogram = vec![0u64; 1];
        for c in counts {
            let c = c as usize;
            if c >= histogram.len() {
                histogram.resize(c + 1, 0);
            }
            histogram[c] += 1;
        }
        Distribution {
            width,
            height,
            fragments,
            histogram,
        }
    }

    /// From a row of Table 4-1: `n[k]` pixels hold `k + 1` transparent fragments.
    pub fn from_table(width: u32, height: u32, fragments: u64, n: &[u64]) -> Self {
        let pixels = u64::from(width) * u64::from(height);
        let covered: u64 = n.iter().sum();
        let mut histogram = vec![pixels.saturating_sub(covered)];
        histogram.extend_from_slice(n);
        while histogram.len() > 1 && histogram.last() == Some(&0) {
            histogram.pop();
        }
        Distribution {
            width,
            height,
            fragments,
            histogram,
        }
    }

    /// `W·H`.
    pub fn pixels(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height)
    }

    /// `N_i` for `i ≥ 1`, with `i`.
    fn rows(&self) -> impl Iterator<Item = (u64, u64)> + '_ {
        self.histogram
            .iter()
            .enumerate()
            .skip(1)
            .map(|(i, &n)| (i as u64, n))
    }

    /// `N_f = Σ N_i·i`.
    pub fn transparent_fragments(&self) -> u64 {
        self.rows().map(|(i, n)| i * n).sum()
    }

    /// `Σ_{i≥1} N_i`.
    pub fn transparent_pixels(&self) -> u64 {
        self.rows().map(|(_, n)| n).sum()
    }

    /// Table 4-1's "no. of transparent fragments per transparent pixel".
    pub fn fragments_per_transparent_pixel(&self) -> f64 {
        match self.transparent_pixels() {
            0 => 0.0,
            p => self.transparent_fragments() as f64 / p as f64,
        }
    }

    /// Table 4-1's transparency density: transparent pixels over the display resolution.
    pub fn transparency_density(&self) -> f64 {
        self.transparent_pixels() as f64 / self.pixels().max(1) as f64
    }

    /// The most transparent fragments a pixel holds (`n_max`).
    pub fn max_fragments(&self) -> u32 {
        (self.histogram.len() - 1) as u32
    }

    /// WF's `D_avg`: fragments per transparent pixel rounded to nearest (halves up), at least 1.
    pub fn d_avg(&self) -> u32 {
        let (f, p) = (self.transparent_fragments(), self.transparent_pixels());
        if p == 0 {
            return 1;
        }
        // round(f / p) with halves up, in integers
        ((2 * f + p) / (2 * p)).max(1) as u32
    }

    /// `Σ_p ⌈n_p / per_section⌉`: sections of `per_section` fragments the pixels need.
    pub fn sections(&self, per_section: u32) -> u64 {
        let l = u64::from(per_section.max(1));
        self.rows().map(|(i, n)| i.div_ceil(l) * n).sum()
    }

    /// WF's `N_A = Σ_p (⌈n_p / D⌉ − 1)`: sections beyond each pixel's own.
    pub fn overflow_sections(&self, per_section: u32) -> u64 {
        let l = u64::from(per_section.max(1));
        self.rows().map(|(i, n)| (i.div_ceil(l) - 1) * n).sum()
    }
}

/// Each pixel's colour lengths (`lz::rgb_length`) and alpha shifts (`lz::alpha_shift`) in storage
/// order, for the leading-zeros figures.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ColourTrace {
    offsets: Vec<u32>,
    lengths: Vec<u8>,
    shifts: Vec<u8>,
}

impl ColourTrace {
    /// From each pixel's colours in storage order.
    pub fn from_runs<'a>(runs: impl IntoIterator<Item = &'a [Rgba8]>) -> Self {
        let mut t = ColourTrace {
            offsets: vec![0],
            ..Self::default()
        };
        for run in runs {
            for c in run {
                let [r, g, b, a] = c.0;
                t.lengths.push(lz::rgb_length([r, g, b]) as u8);
                t.shifts.push(lz::alpha_shift(a) as u8);
            }
            t.offsets.push(t.lengths.len() as u32);
        }
        t
    }

    /// Fragments in the trace.
    pub fn len(&self) -> usize {
        self.lengths.len()
    }

    /// True if the trace holds no fragment.
    pub fn is_empty(&self) -> bool {
        self.lengths.is_empty()
    }

    /// Pixel `p`'s colour lengths; with `lossy`, after the thesis's alpha shift.
    pub fn pixel(&self, p: usize, lossy: bool) -> impl Iterator<Item = u8> + '_ {
        let r = self.offsets[p] as usize..self.offsets[p + 1] as usize;
        self.lengths[r.clone()]
            .iter()
            .zip(&self.shifts[r])
            .map(move |(&len, &s)| if lossy { len.saturating_sub(s) } else { len })
    }

    /// Pixels in the trace.
    pub fn pixels(&self) -> usize {
        self.offsets.len() - 1
    }

    /// `histogram[len]`: fragments whose colour keeps `len` bits (0..=8) — our Figure 3-10.
    pub fn length_histogram(&self, lossy: bool) -> [u64; 9] {
        let mut h = [0u64; 9];
        for p in 0..self.pixels() {
            for len in self.pixel(p, lossy) {
                h[len as usize] += 1;
            }
        }
        h
    }
}

/// Which fragments count as transparent.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Transparency {
    /// Every fragment (our scenes are translucent; the default).
    #[default]
    All,
    /// Fragments with alpha 255 are opaque and go to the frame buffer; the transparent fragments
    /// are those in front of the pixel's nearest opaque one — what R-buffer and WF keep after
    /// their phase 2.
    OpaqueSplit,
}

/// The distribution and colour trace of a captured frame.
pub fn frame_model(frame: &DeepFrame, transparency: Transparency) -> (Distribution, ColourTrace) {
    let pixels = frame.width() as usize * frame.height() as usize;
    let transparent_run = |p: usize| {
        let colors = frame.run(p).color;
        match transparency {
            Transparency::All => colors,
            Transparency::OpaqueSplit => {
                let n = colors.iter().position(|c| c.alpha() == 255);
                &colors[..n.unwrap_or(colors.len())]
            }
        }
    };
    let distribution = Distribution::from_counts(
        frame.width(),
        frame.height(),
        frame.fragment_count() as u64,
        (0..pixels).map(|p| transparent_run(p).len() as u32),
    );
    let trace = ColourTrace::from_runs((0..pixels).map(transparent_run));
    (distribution, trace)
}

/// The byte sizes the model uses; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sizes {
    /// `S_f`: an R-buffer fragment (x, y, z, RGBA).
    pub rbuffer_fragment: u64,
    /// A WF / TFSS fragment (z, RGBA).
    pub fragment: u64,
    /// `Z`: a depth value.
    pub z: u64,
    /// `S_A`: an address.
    pub address: u64,
    /// R-buffer state memory, bits per pixel.
    pub state_bits: u64,
    /// Bits per Length-table entry.
    pub length_bits: u64,
}

impl Default for Sizes {
    /// The sizes strata evaluates its frames with (4-byte addresses).
    fn default() -> Self {
        Sizes {
            rbuffer_fragment: 12,
            fragment: 8,
            z: 4,
            address: 4,
            state_bits: 3,
            length_bits: u64::from(lz::LENGTH_BITS),
        }
    }
}

impl Sizes {
    /// The sizes closest to the thesis's quoted figures: 2-byte addresses (see the module docs).
    pub fn seed_fit() -> Self {
        Sizes {
            address: 2,
            ..Self::default()
        }
    }
}

/// One technique's memory, part by part.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Memory {
    /// The technique as the thesis's figures name it: `R-buffer`, `WF(2)`, `TFSS(2)`,
    /// `TFSS(2, 13)` (with `M_section`), …
    pub name: String,
    /// `(part, bytes)`, e.g. `("T-buffer", 401120)`.
    pub parts: Vec<(&'static str, u64)>,
}

impl Memory {
    /// Bytes in all.
    pub fn total(&self) -> u64 {
        self.parts.iter().map(|p| p.1).sum()
    }

    /// The bytes of one part, 0 if absent.
    pub fn part(&self, name: &str) -> u64 {
        self.parts.iter().find(|p| p.0 == name).map_or(0, |p| p.1)
    }
}

/// R-buffer (Table 4-2 row 1).
pub fn rbuffer(d: &Distribution, s: &Sizes) -> Memory {
    Memory {
        name: "R-buffer".into(),
        parts: vec![
            ("R-buffer", d.transparent_fragments() * s.rbuffer_fragment),
            ("2nd z-buffer", d.pixels() * s.z),
            ("state memory", (d.pixels() * s.state_bits).div_ceil(8)),
        ],
    }
}

/// WF with sections of `d_avg` fragments (Table 4-2 row 2).
pub fn wf(d: &Distribution, s: &Sizes, d_avg: u32) -> Memory {
    let sections = d.pixels() + d.overflow_sections(d_avg);
    Memory {
        name: format!("WF({d_avg})"),
        parts: vec![
            ("M-buffer", sections * u64::from(d_avg) * s.fragment),
            ("pointer memory", sections * s.address),
        ],
    }
}

/// TFSS with sections of `l_num` fragments (Table 4-2 row 3).
pub fn tfss(d: &Distribution, s: &Sizes, l_num: u32) -> Memory {
    let n_s = d.sections(l_num);
    Memory {
        name: format!("TFSS({l_num})"),
        parts: vec![
            ("T-buffer", n_s * u64::from(l_num) * s.fragment),
            ("SSA table", d.pixels() * s.address),
            ("NSA table", n_s * s.address),
        ],
    }
}

/// Bits of the colour area of a packed section of `l_num` slots sized for `b`-bit components:
/// alpha and three components per slot, and never less than one full-width record.
pub fn colour_area_bits(l_num: u32, b: u32) -> u32 {
    (l_num * lz::record_bits(b.min(8))).max(FULL_RECORD_BITS)
}

/// Sections one pixel needs when fragments with colour lengths `lengths` (in storage order) are
/// packed into sections of `l_num` slots and `area` colour bits: a section takes fragments while
/// it has a free slot and the next record (`lz::record_bits`) fits in what is left of its area;
/// a record that does not fit seals it. `area` must hold a full record.
pub fn packed_sections_of(lengths: impl IntoIterator<Item = u8>, l_num: u32, area: u32) -> u64 {
    debug_assert!(area >= FULL_RECORD_BITS);
    // Start "full" so that the first fragment opens the first section.
    let (mut sections, mut slots, mut used) = (0u64, l_num, 0u32);
    for len in lengths {
        let bits = lz::record_bits(u32::from(len));
        if slots == l_num || used + bits > area {
            sections += 1;
            (slots, used) = (0, 0);
        }
        slots += 1;
        used += bits;
    }
    sections
}

/// [`packed_sections_of`] for every budget `b = 0..=8` at once (`[b]`), in one pass.
pub fn packed_sections_per_budget(lengths: impl IntoIterator<Item = u8>, l_num: u32) -> [u64; 9] {
    let area: [u32; 9] = std::array::from_fn(|b| colour_area_bits(l_num, b as u32));
    let (mut sections, mut slots, mut used) = ([0u64; 9], [l_num; 9], [0u32; 9]);
    for len in lengths {
        let bits = lz::record_bits(u32::from(len));
        for b in 0..9 {
            let open = slots[b] == l_num || used[b] + bits > area[b];
            sections[b] += u64::from(open);
            slots[b] = if open { 1 } else { slots[b] + 1 };
            used[b] = if open { bits } else { used[b] + bits };
        }
    }
    sections
}

/// [`packed_sections_of`] summed over every pixel of `trace`.
pub fn packed_sections(trace: &ColourTrace, l_num: u32, b: u32, lossy: bool) -> u64 {
    let area = colour_area_bits(l_num, b);
    (0..trace.pixels())
        .map(|p| packed_sections_of(trace.pixel(p, lossy), l_num, area))
        .sum()
}

/// TFSS with leading-zeros elimination at colour budget `b`: `TFSS(L_num, M_section)` with
/// sections of `32·L_num` depth bits plus the colour area, rounded up to bytes, and the Length
/// table (`⌈length_bits·L_num / 8⌉` bytes a section). `lossy` applies the thesis's alpha shift.
pub fn tfss_lz(
    d: &Distribution,
    trace: &ColourTrace,
    s: &Sizes,
    l_num: u32,
    b: u32,
    lossy: bool,
) -> Memory {
    let n_s = packed_sections(trace, l_num, b, lossy);
    let m_section =
        (u64::from(l_num) * s.z * 8 + u64::from(colour_area_bits(l_num, b))).div_ceil(8);
    Memory {
        name: format!(
            "TFSS({l_num}, {m_section}){}",
            if lossy {
                " LZ+alpha shift (lossy)"
            } else {
                " LZ"
            }
        ),
        parts: vec![
            ("T-buffer", n_s * m_section),
            ("SSA table", d.pixels() * s.address),
            ("NSA table", n_s * s.address),
            (
                "Length table",
                n_s * (s.length_bits * u64::from(l_num)).div_ceil(8),
            ),
        ],
    }
}

/// The colour budget `b` (0..=8) with the least [`tfss_lz`] memory, and that memory; among
/// equals the widest budget.
pub fn tfss_lz_best(
    d: &Distribution,
    trace: &ColourTrace,
    s: &Sizes,
    l_num: u32,
    lossy: bool,
) -> (u32, Memory) {
    (0..=8u32)
        .rev()
        .map(|b| (b, tfss_lz(d, trace, s, l_num, b, lossy)))
        .min_by_key(|(_, m)| m.total())
        .expect("nine budgets")
}

/// The layouts beside the thesis's techniques; see the module docs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layouts {
    /// strata's DeepFrame: offsets + 12-byte fragment columns.
    pub deep_frame: Memory,
    /// The S-buffer's regions: offsets + fill counters + 12-byte slots.
    pub sbuffer: Memory,
    /// The linked-list A-buffer: heads + 16-byte nodes + counter.
    pub linked_list: Memory,
    /// Compact runs with the thesis's 8-byte fragment.
    pub compact: Memory,
    /// Compact runs with leading-zeros-eliminated colours (lossless), if a trace was given.
    pub compact_lz: Option<Memory>,
}

/// Bytes of the per-pixel count of the compact layouts: 1, or 2 if a pixel holds more than 255.
fn count_bytes(d: &Distribution) -> u64 {
    if d.max_fragments() <= 255 { 1 } else { 2 }
}

/// The layouts of [`Layouts`] holding the same transparent fragments as `d`.
pub fn layouts(d: &Distribution, trace: Option<&ColourTrace>, s: &Sizes) -> Layouts {
    let (px, f) = (d.pixels(), d.transparent_fragments());
    let blocks = px.div_ceil(COMPACT_OFFSET_EVERY);
    let counts = ("counts", px * count_bytes(d));
    Layouts {
        deep_frame: Memory {
            name: "DeepFrame".into(),
            parts: vec![("offsets", 4 * (px + 1)), ("fragments", 12 * f)],
        },
        sbuffer: Memory {
            name: "S-buffer regions".into(),
            parts: vec![
                ("offsets", 4 * (px + 1)),
                ("fill", 4 * px),
                ("fragments", 12 * f),
            ],
        },
        linked_list: Memory {
            name: "linked list".into(),
            parts: vec![("heads", 4 * px), ("nodes", 16 * f), ("counter", 4)],
        },
        compact: Memory {
            name: "compact runs".into(),
            parts: vec![
                counts,
                ("block offsets", 4 * blocks),
                ("fragments", s.fragment * f),
            ],
        },
        compact_lz: trace.map(|t| {
            let bits: u64 = t
                .lengths
                .iter()
                .map(|&len| 8 * s.z + s.length_bits + u64::from(lz::record_bits(u32::from(len))))
                .sum();
            Memory {
                name: "compact runs LZ".into(),
                parts: vec![
                    counts,
                    ("block offsets", 4 * blocks),
                    ("fragments", bits.div_ceil(8)),
                ],
            }
        }),
    }
}

/// strata's own TFSS store without leading-zeros elimination (12-byte fragments, 4-byte
/// addresses): what `Tfss::memory().used()` reports for the frame.
pub fn tfss_store(d: &Distribution, l_num: u32) -> Memory {
    let n_s = d.sections(l_num);
    Memory {
        name: format!("TFSS store({l_num})"),
        parts: vec![
            ("T-buffer", n_s * 12 * u64::from(l_num)),
            ("SSA table", 4 * d.pixels()),
            ("NSA table", 4 * n_s),
            ("counter", 4),
        ],
    }
}

/// One technique's cycles in the model of §4.3.2.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Time {
    /// `R-buffer`, `WF`, `TFSS`.
    pub name: &'static str,
    /// `(memory, accesses)`.
    pub accesses: Vec<(&'static str, u64)>,
    /// Computation cycles.
    pub computation: u64,
}

impl Time {
    /// Memory accesses in all.
    pub fn access_total(&self) -> u64 {
        self.accesses.iter().map(|a| a.1).sum()
    }

    /// Execution time: one cycle per access plus the computation.
    pub fn cycles(&self) -> u64 {
        self.access_total() + self.computation
    }
}

/// `Σ N_i·f(i)`.
fn sum_over(d: &Distribution, f: impl Fn(u64) -> u64) -> u64 {
    d.rows().map(|(i, n)| n * f(i)).sum()
}

/// R-buffer's accesses and computation.
pub fn rbuffer_time(d: &Distribution) -> Time {
    let f_r = sum_over(d, |i| i * (i + 1) / 2);
    Time {
        name: "R-buffer",
        accesses: vec![
            ("R-buffer", f_r),
            ("2nd z-buffer", f_r),
            ("frame buffer", d.transparent_fragments()),
        ],
        computation: sum_over(d, |i| i * (i + 1) / 2),
    }
}

/// WF's computation, `Σ N_i·(i(i−1)/2 + 1)` (shared by TFSS).
fn wf_computation(d: &Distribution) -> u64 {
    sum_over(d, |i| i * (i - 1) / 2 + 1)
}

/// WF's accesses and computation.
pub fn wf_time(d: &Distribution) -> Time {
    Time {
        name: "WF",
        accesses: vec![("M-buffer", d.transparent_fragments())],
        computation: wf_computation(d),
    }
}

/// TFSS's accesses and computation (the same for every `L_num`).
pub fn tfss_time(d: &Distribution) -> Time {
    Time {
        name: "TFSS",
        accesses: vec![
            ("T-buffer", d.transparent_fragments()),
            ("SSA table", d.transparent_pixels()),
        ],
        computation: wf_computation(d),
    }
}

/// Accesses of TFSS's store flow (Figure 3-8) with sections of `l_num`: per fragment `k` (0-based)
/// of a pixel one SSA read, `⌊k / L_num⌋` NSA reads and one T-buffer write, plus one SSA or NSA
/// write per section allocated. Beyond the thesis, which times only the read side.
pub fn tfss_store_accesses(d: &Distribution, l_num: u32) -> u64 {
    let l = u64::from(l_num.max(1));
    sum_over(d, |i| {
        let walks: u64 = (0..i).map(|k| k / l).sum();
        2 * i + walks + i.div_ceil(l)
    })
}

/// `1 − ours / theirs`: the reduction rate Figures 4-4, 4-6 and 4-7 print, as a fraction.
pub fn reduction(ours: u64, theirs: u64) -> f64 {
    if theirs == 0 {
        0.0
    } else {
        1.0 - ours as f64 / theirs as f64
    }
}

/// One `L_num`'s TFSS figures.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TfssRow {
    /// `L_num`.
    pub l_num: u32,
    /// Without leading-zeros elimination.
    pub plain: Memory,
    /// With lossless leading-zeros elimination, at the best budget `b`.
    pub lz: Option<(u32, Memory)>,
    /// With the thesis's lossy alpha shift too, at its best budget.
    pub lz_lossy: Option<(u32, Memory)>,
    /// strata's TFSS store (12-byte fragments), without leading-zeros elimination.
    pub store: Memory,
    /// Store-flow accesses ([`tfss_store_accesses`]).
    pub store_accesses: u64,
}

/// Every figure of the model for one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Evaluation {
    /// The sizes used.
    pub sizes: Sizes,
    /// Table 4-1.
    pub distribution: Distribution,
    /// R-buffer memory.
    pub rbuffer: Memory,
    /// WF memory with `D_avg` sections.
    pub wf: Memory,
    /// TFSS for `L_num = 1..=l_num_max`.
    pub tfss: Vec<TfssRow>,
    /// strata's layouts.
    pub layouts: Layouts,
    /// R-buffer, WF and TFSS cycles.
    pub time: [Time; 3],
}

/// Evaluates a frame: memory for `L_num = 1..=l_num_max` (leading-zeros rows only with a trace)
/// and the time model.
pub fn evaluate(
    d: &Distribution,
    trace: Option<&ColourTrace>,
    sizes: &Sizes,
    l_num_max: u32,
) -> Evaluation {
    let tfss = (1..=l_num_max.max(1))
        .map(|l| TfssRow {
            l_num: l,
            plain: tfss(d, sizes, l),
            lz: trace.map(|t| tfss_lz_best(d, t, sizes, l, false)),
            lz_lossy: trace.map(|t| tfss_lz_best(d, t, sizes, l, true)),
            store: tfss_store(d, l),
            store_accesses: tfss_store_accesses(d, l),
        })
        .collect();
    Evaluation {
        sizes: *sizes,
        distribution: d.clone(),
        rbuffer: rbuffer(d, sizes),
        wf: wf(d, sizes, d.d_avg()),
        tfss,
        layouts: layouts(d, trace, sizes),
        time: [rbuffer_time(d), wf_time(d), tfss_time(d)],
    }
}

#[cfg(test)]
mod tests;
