//! `examples/c/vlsync_wire.h` describes exactly the Rust layouts: compiled by
//! the system C compiler, every size and offset printed by C equals Rust's.

use core::mem::{offset_of, size_of};
use std::path::Path;
use std::process::Command;
use vlsync_common::wire::{OffsetEstimate, SignatureSample, Status};

#[test]
fn c_header_matches_the_rust_layouts() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/c");
    let tmp = std::env::temp_dir().join(format!("vlsync-c-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let src = tmp.join("layout.c");
    std::fs::write(
        &src,
        r#"#include <stdio.h>
#include "vlsync_wire.h"
int main(void) {
  printf("%zu %zu %zu %zu\n", sizeof(vlsync_signature_sample), offsetof(vlsync_signature_sample, value),
         offsetof(vlsync_signature_sample, seq), offsetof(vlsync_signature_sample, flags));
  printf("%zu %zu %zu %zu %zu\n", sizeof(vlsync_offset_estimate), offsetof(vlsync_offset_estimate, drift),
         offsetof(vlsync_offset_estimate, peak_ratio), offsetof(vlsync_offset_estimate, state),
         offsetof(vlsync_offset_estimate, polarity));
  printf("%zu %zu %zu %zu\n", sizeof(vlsync_status), offsetof(vlsync_status, budget_overruns),
         offsetof(vlsync_status, events_dropped), offsetof(vlsync_status, degraded));
  return 0;
}
"#,
    )
    .unwrap();
    let exe = tmp.join("layout");
    vlsync_tests::compile(&src, &exe, false, &dir, &[]);
    let out = Command::new(&exe).output().unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    let expect = format!(
        "{} {} {} {}\n{} {} {} {} {}\n{} {} {} {}\n",
        size_of::<SignatureSample>(),
        offset_of!(SignatureSample, value),
        offset_of!(SignatureSample, seq),
        offset_of!(SignatureSample, flags),
        size_of::<OffsetEstimate>(),
        offset_of!(OffsetEstimate, drift),
        offset_of!(OffsetEstimate, peak_ratio),
        offset_of!(OffsetEstimate, state),
        offset_of!(OffsetEstimate, polarity),
        size_of::<Status>(),
        offset_of!(Status, budget_overruns),
        offset_of!(Status, events_dropped),
        offset_of!(Status, degraded),
    );
    assert_eq!(text, expect);
    std::fs::remove_dir_all(&tmp).unwrap();
}
