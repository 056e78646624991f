//! Huge declared counts cost memory in proportion to the file, not to the count it declares.
//!
//! A 200-byte PLY or OFF file can declare four billion vertices and faces; a loader that trusted
//! the header would reserve tens of gigabytes before finding out the data is missing. This test
//! binary runs under a counting global allocator with a limit ([`cap::Cap`]): each hostile file is
//! parsed with at most [`BUDGET`] bytes allocated on top of what was live before. An allocation
//! past the budget makes the allocator return null, and the process aborts with `memory
//! allocation of N bytes failed` — the test fails loudly, never slowly.
//!
//! Everything runs in one `#[test]` so that no other test allocates in parallel while a limit is
//! set (the count and the limit are process-wide).

use std::alloc::System;
use std::path::Path;

use cap::Cap;
use strata_scene::load::{Format, LoadError, LoadErrorKind, Location, parse_model};

#[global_allocator]
static ALLOCATOR: Cap<System> = Cap::new(System, usize::MAX);

/// Bytes a hostile file of under a kilobyte may make the loader allocate, on top of what was live
/// before. Four billion declared vertices would need 48 GB.
const BUDGET: usize = 1 << 20;

/// Parses `bytes` as `format` with at most [`BUDGET`] more bytes allocated at any moment, and
/// returns the error it must fail with.
fn parse_within_budget(format: Format, name: &str, bytes: &[u8]) -> LoadError {
    let live = ALLOCATOR.allocated();
    ALLOCATOR
        .set_limit(live + BUDGET)
        .expect("the limit is above what is allocated");
    let result = parse_model(bytes, format, Path::new(name));
    ALLOCATOR
        .set_limit(usize::MAX)
        .expect("no limit is below what is allocated");
    let e = result.expect_err("a file declaring data it does not hold must fail");
    assert!(e.to_string().starts_with(&format!("{name}: ")), "{e}");
    e
}

fn check_at(e: &LoadError, location: Location, contains: &str) {
    assert_eq!(e.location, Some(location), "{e}");
    assert!(e.to_string().contains(contains), "{e}");
}

/// The allocator really counts: without this, every budget below would hold trivially.
fn allocator_counts() {
    let before = ALLOCATOR.allocated();
    let block = vec![1u8; 3 * BUDGET];
    assert!(
        ALLOCATOR.allocated() >= before + block.len(),
        "the counting allocator is installed"
    );
    drop(block);
}

fn ply_huge_counts() {
    for format in ["ascii", "binary_little_endian", "binary_big_endian"] {
        let text = format!(
            "ply\nformat {format} 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\n\
             property float z\nelement face 4000000000\nproperty list uint uint vertex_indices\nend_header\n\
             0 0 0 1 2 3 4 5 6 7 8 9\n"
        );
        let e = parse_within_budget(Format::Ply, "huge.ply", text.as_bytes());
        assert!(
            matches!(
                e.kind,
                LoadErrorKind::Truncated(_) | LoadErrorKind::Syntax(_)
            ),
            "{format}: {e}"
        );
    }
    // Too many vertices for u32 indices is refused in the header.
    let e = parse_within_budget(
        Format::Ply,
        "huge.ply",
        b"ply\nformat binary_little_endian 1.0\nelement vertex 5000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
    );
    assert!(matches!(e.kind, LoadErrorKind::Unsupported(_)), "{e}");
    check_at(
        &e,
        Location::Line(3),
        "5000000000 vertices exceed the limit of 2^32",
    );
    // A face list claiming 2^32-1 indices with 12 bytes left.
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uint uint vertex_indices\nend_header\n".to_vec();
    let body = bytes.len() as u64;
    bytes.extend_from_slice(&[0; 36]);
    bytes.extend_from_slice(&u32::MAX.to_le_bytes());
    bytes.extend_from_slice(&[0; 12]);
    let e = parse_within_budget(Format::Ply, "huge.ply", &bytes);
    check_at(
        &e,
        Location::Byte(body + 36 + 4 + 12),
        "unexpected end of file in face 0",
    );
}

fn off_huge_counts() {
    let e = parse_within_budget(
        Format::Off,
        "huge.off",
        b"OFF\n4000000000 4000000000 0\n0 0 0\n",
    );
    check_at(&e, Location::Line(4), "unexpected end of file in vertex 1");
    let e = parse_within_budget(
        Format::Off,
        "huge.off",
        b"OFF\n3 4000000000 0\n0 0 0\n0 0 0\n0 0 0\n3 0 1 2\n",
    );
    check_at(&e, Location::Line(7), "unexpected end of file in face 1");
}

#[test]
fn huge_declared_counts_allocate_for_the_file_not_the_count() {
    allocator_counts();
    ply_huge_counts();
    off_huge_counts();
}
