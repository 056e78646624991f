//! The lane width of setup and the scan, and how a batch's values reach its samples' lanes.
//!
//! Setup classifies triangles `L` at a time ([`crate::coverage::Batch`]) and shades the
//! micro-triangles' samples `L` at a time ([`crate::shade_lanes::MicroShader`]); the scan shades a
//! larger triangle's samples `L` at a time ([`crate::shade_lanes::SpanShader`]). `L` is the
//! number of 32-bit lanes in one register of the widest instruction set the CPU has, and it is
//! chosen at run time together with that set ([`dispatch`]):
//!
//! | CPU | compiled for | `L` | samples reach their lanes by |
//! | --- | --- | ---: | --- |
//! | x86-64 with AVX-512 (F, BW, CD, DQ, VL) | pulp's `V4` | 16 | `vpermd`/`vpermps` on 512 bits ([`pulp::x86::V4`]) |
//! | x86-64 with AVX2 | pulp's `V3` | 8 | `vpermd`/`vpermps` on 256 bits ([`pulp::x86::V3`]) |
//! | anything else (SSE2, NEON, scalar) | what [`pulp::Arch`] finds | 8 | rounds ([`Rounds`]) |
//!
//! A batch of 16 triangles is one register a quantity on AVX-512, so classifying it and shading
//! its samples take about the instructions a batch of 8 took on AVX2, for twice the triangles.
//! On the full dragon (one thread, Intel Xeon with AVX-512) that took setup from 20–22 to
//! 15–16 ms.
//!
//! `STRATA_LANES=8` in the environment makes a CPU with AVX-512 run the AVX2 path instead, so
//! that the two widths can be compared in one binary on one machine (a CPU that splits 512-bit
//! operations in two, such as AMD's Zen 4, may gain less from sixteen). The frames are the same
//! either way.
//!
//! # Permutes
//!
//! A packed pass ([`crate::shade_lanes`]) puts a batch's covered samples one after the other,
//! `L` a pass, and moves each triangle value into its samples' lanes: `out[s] = a[idx[s]]`,
//! which a lane permute does in one instruction. [`Permute::PACKED`] says whether the
//! implementation has such an instruction; where it does not ([`Rounds`]) setup shades in rounds
//! instead (round `r` takes the `r`-th sample of every lane), which needs no permute. Every
//! implementation computes the same values, so the width and the packing change which lane
//! computes a sample, never its bits: the arithmetic of a lane is IEEE and the same on every
//! instruction set (no fused multiply-adds).

/// Moves lanes of a batch quantity (a lane a triangle) into sample lanes: `out[s] = a[idx[s]]`
/// for indices below `L`. An index of `L` or more gives some lane's value (every
/// implementation here reads lane `idx % L`): the packed passes give the outputs past a
/// batch's last sample index `L` and mark them not kept.
pub trait Permute<const L: usize>: Copy {
    /// True if the permute is one instruction, so that setup packs a batch's samples into
    /// passes ([`crate::shade_lanes`]); false to shade in rounds, which need no permute.
    const PACKED: bool;

    /// `a[idx[s]]` in lane `s`.
    fn u32s(self, a: [u32; L], idx: [u32; L]) -> [u32; L];

    /// `a[idx[s]]` in lane `s`.
    fn f32s(self, a: [f32; L], idx: [u32; L]) -> [f32; L];

    /// `a[idx[s]]` in lane `s`.
    #[inline(always)]
    fn i32s(self, a: [i32; L], idx: [u32; L]) -> [i32; L] {
        self.u32s(a.map(|v| v as u32), idx).map(|v| v as i32)
    }
}

/// Shading in rounds, without a permute instruction (SSE2, NEON, scalar). Its permute is a
/// lane-by-lane copy, correct but not used by setup.
#[derive(Clone, Copy, Debug, Default)]
pub struct Rounds;

impl<const L: usize> Permute<L> for Rounds {
    const PACKED: bool = false;

    #[inline(always)]
    fn u32s(self, a: [u32; L], idx: [u32; L]) -> [u32; L] {
        std::array::from_fn(|s| a[idx[s] as usize % L])
    }

    #[inline(always)]
    fn f32s(self, a: [f32; L], idx: [u32; L]) -> [f32; L] {
        std::array::from_fn(|s| a[idx[s] as usize % L])
    }
}

/// Packed passes with a lane-by-lane permute: what the AVX2 and AVX-512 paths compute, on any
/// CPU and at any width, so that the tests check the packing itself everywhere.
#[cfg(test)]
#[derive(Clone, Copy, Debug, Default)]
pub struct PackedScalar;

#[cfg(test)]
impl<const L: usize> Permute<L> for PackedScalar {
    const PACKED: bool = true;

    fn u32s(self, a: [u32; L], idx: [u32; L]) -> [u32; L] {
        Rounds.u32s(a, idx)
    }

    fn f32s(self, a: [f32; L], idx: [u32; L]) -> [f32; L] {
        Rounds.f32s(a, idx)
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::Permute;
    use core::arch::x86_64::{__m256, __m256i, __m512, __m512i};
    use pulp::bytemuck::cast;
    use pulp::x86::{V3, V4};

    impl Permute<8> for V3 {
        const PACKED: bool = true;

        #[inline(always)]
        fn u32s(self, a: [u32; 8], idx: [u32; 8]) -> [u32; 8] {
            let (a, idx) = (cast::<_, __m256i>(a), cast::<_, __m256i>(idx));
            cast(self.avx2._mm256_permutevar8x32_epi32(a, idx))
        }

        #[inline(always)]
        fn f32s(self, a: [f32; 8], idx: [u32; 8]) -> [f32; 8] {
            let (a, idx) = (cast::<_, __m256>(a), cast::<_, __m256i>(idx));
            cast(self.avx2._mm256_permutevar8x32_ps(a, idx))
        }

        #[inline(always)]
        fn i32s(self, a: [i32; 8], idx: [u32; 8]) -> [i32; 8] {
            let (a, idx) = (cast::<_, __m256i>(a), cast::<_, __m256i>(idx));
            cast(self.avx2._mm256_permutevar8x32_epi32(a, idx))
        }
    }

    impl Permute<16> for V4 {
        const PACKED: bool = true;

        #[inline(always)]
        fn u32s(self, a: [u32; 16], idx: [u32; 16]) -> [u32; 16] {
            let (a, idx) = (cast::<_, __m512i>(a), cast::<_, __m512i>(idx));
            cast(self.avx512f._mm512_permutexvar_epi32(idx, a))
        }

        #[inline(always)]
        fn f32s(self, a: [f32; 16], idx: [u32; 16]) -> [f32; 16] {
            let (a, idx) = (cast::<_, __m512>(a), cast::<_, __m512i>(idx));
            cast(self.avx512f._mm512_permutexvar_ps(idx, a))
        }

        #[inline(always)]
        fn i32s(self, a: [i32; 16], idx: [u32; 16]) -> [i32; 16] {
            let (a, idx) = (cast::<_, __m512i>(a), cast::<_, __m512i>(idx));
            cast(self.avx512f._mm512_permutexvar_epi32(idx, a))
        }
    }
}

/// Work compiled once per lane width and instruction set; see [`dispatch`].
pub trait LaneJob {
    /// What the job returns.
    type Output;

    /// Runs the job `L` lanes at a time with `permute`. Implementations should be
    /// `#[inline(always)]`, so that they are compiled for the instruction set [`dispatch`] picked.
    fn run<const L: usize, P: Permute<L>>(self, permute: P) -> Self::Output;
}

/// Runs `job` compiled for the widest instruction set the CPU has, at that set's lane width (see
/// the table in the module docs), or for AVX2 where `STRATA_LANES=8` asks for eight lanes.
#[inline]
pub fn dispatch<J: LaneJob>(job: J) -> J::Output {
    #[cfg(target_arch = "x86_64")]
    {
        // `Simd::vectorize`, not the types' own `vectorize`, which takes a closure.
        if let Some(v4) = pulp::x86::V4::try_new().filter(|_| !eight_lanes_asked()) {
            return pulp::Simd::vectorize(v4, Compiled::<J, 16, _> { job, permute: v4 });
        }
        if let Some(v3) = pulp::x86::V3::try_new() {
            return pulp::Simd::vectorize(v3, Compiled::<J, 8, _> { job, permute: v3 });
        }
    }
    pulp::Arch::new().dispatch(Compiled::<J, 8, _> {
        job,
        permute: Rounds,
    })
}

/// The environment variable that caps the lane width; see [`requested_lanes`].
pub const LANES_VAR: &str = "STRATA_LANES";

/// The lane width a value of [`LANES_VAR`] asks for: `None` (the widest the CPU has) if unset
/// or `16`, `Some(8)` for `8`, and an error naming the variable for anything else. The
/// rasteriser itself treats an error as unset (it has no one to tell); `strata` refuses to
/// start with it, so that a mistyped value cannot silently measure the wrong width.
pub fn requested_lanes(value: Option<&std::ffi::OsStr>) -> Result<Option<usize>, String> {
    match value.map(|v| v.to_str()) {
        None => Ok(None),
        Some(Some("16")) => Ok(None),
        Some(Some("8")) => Ok(Some(8)),
        Some(v) => Err(format!(
            "{LANES_VAR}={} is not a lane width: use 8 (the AVX2 path where the CPU has \
             AVX-512) or 16, or leave it unset (the widest the CPU has)",
            v.unwrap_or("(not UTF-8)")
        )),
    }
}

/// True if the environment asks for eight lanes ([`requested_lanes`]); read once.
fn eight_lanes_asked() -> bool {
    static ASKED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *ASKED.get_or_init(|| requested_lanes(std::env::var_os(LANES_VAR).as_deref()) == Ok(Some(8)))
}

/// A [`LaneJob`] with its width and permute, for [`pulp::Simd::vectorize`].
struct Compiled<J, const L: usize, P> {
    job: J,
    permute: P,
}

impl<J: LaneJob, const L: usize, P: Permute<L>> pulp::WithSimd for Compiled<J, L, P> {
    type Output = J::Output;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> J::Output {
        self.job.run::<L, P>(self.permute)
    }
}

/// Every permute the tests run a lane computation with: both widths in rounds and packed with a
/// lane-by-lane copy on any CPU, then AVX2's and AVX-512's where this CPU has them (a note on
/// stderr where it has not).
#[cfg(test)]
pub(crate) trait EveryPermute {
    /// Runs the computation `L` lanes wide with `permute`.
    fn run<const L: usize, P: Permute<L>>(&mut self, permute: P);
}

/// Runs `test` with every permute; see [`EveryPermute`].
#[cfg(test)]
pub(crate) fn with_every_permute(test: &mut impl EveryPermute) {
    test.run::<8, _>(Rounds);
    test.run::<16, _>(Rounds);
    test.run::<8, _>(PackedScalar);
    test.run::<16, _>(PackedScalar);
    #[cfg(target_arch = "x86_64")]
    {
        match pulp::x86::V3::try_new() {
            Some(v3) => test.run::<8, _>(v3),
            None => eprintln!("no AVX2 on this CPU: its permute is not tested here"),
        }
        match pulp::x86::V4::try_new() {
            Some(v4) => test.run::<16, _>(v4),
            None => eprintln!("no AVX-512 on this CPU: its permute is not tested here"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `out[s] = a[idx[s]]` for every rotation of a scattered index pattern, in all three
    /// types, and index `L` (a packed pass's outputs past the last sample) reading lane 0.
    struct PermutesLikeIndexing;
    impl EveryPermute for PermutesLikeIndexing {
        fn run<const L: usize, P: Permute<L>>(&mut self, p: P) {
            let a: [u32; L] = std::array::from_fn(|l| 1000 + 7 * l as u32);
            let f: [f32; L] = std::array::from_fn(|l| -0.5 * l as f32);
            let i: [i32; L] = std::array::from_fn(|l| -3 * l as i32);
            for rot in 0..=L {
                // Rotation L puts index L in lane 0.
                let idx: [u32; L] = std::array::from_fn(|s| match (s, rot) {
                    (0, r) if r == L => L as u32,
                    _ => ((s * 5 + rot) % L) as u32,
                });
                let want = |s: usize| idx[s] as usize % L;
                let (u, g, n) = (p.u32s(a, idx), p.f32s(f, idx), p.i32s(i, idx));
                for s in 0..L {
                    assert_eq!(u[s], a[want(s)], "u32 lane {s} of {L}");
                    assert_eq!(g[s].to_bits(), f[want(s)].to_bits(), "f32 lane {s} of {L}");
                    assert_eq!(n[s], i[want(s)], "i32 lane {s} of {L}");
                }
            }
        }
    }

    #[test]
    fn every_permute_moves_lane_idx_s_into_lane_s() {
        with_every_permute(&mut PermutesLikeIndexing);
    }

    #[test]
    fn the_lanes_variable_takes_8_16_or_nothing() {
        use std::ffi::OsStr;
        assert_eq!(requested_lanes(None), Ok(None));
        assert_eq!(requested_lanes(Some(OsStr::new("16"))), Ok(None));
        assert_eq!(requested_lanes(Some(OsStr::new("8"))), Ok(Some(8)));
        for bad in ["", "4", "32", " 8", "eight", "8x"] {
            let err = requested_lanes(Some(OsStr::new(bad))).unwrap_err();
            assert!(err.starts_with(&format!("STRATA_LANES={bad} ")), "{err}");
        }
    }

    /// A job that reports the width it was given.
    struct Width;
    impl LaneJob for Width {
        type Output = (usize, bool);
        fn run<const L: usize, P: Permute<L>>(self, _: P) -> (usize, bool) {
            (L, P::PACKED)
        }
    }

    #[test]
    fn dispatch_picks_the_widest_lanes_the_cpu_has() {
        let got = dispatch(Width);
        #[cfg(target_arch = "x86_64")]
        {
            let want = if pulp::x86::V4::try_new().is_some() && !eight_lanes_asked() {
                (16, true)
            } else if pulp::x86::V3::try_new().is_some() {
                (8, true)
            } else {
                (8, false)
            };
            assert_eq!(got, want);
        }
        #[cfg(not(target_arch = "x86_64"))]
        assert_eq!(got, (8, false));
    }
}
