//! `examples/c/vlsync_wire.h` describes exactly the Rust layouts: compiled by
//! the system C compiler, every size and offset printed by C equals Rust's, and so
//! do its flag bits, type names, state, polarity and reject codes.

use core::mem::{offset_of, size_of};
use std::path::Path;
use std::process::Command;
use vlsync_common::wire::{
    OffsetEstimate, SignatureSample, Status, FLAG_FIRST, FLAG_SIMULATED, KNOWN_FLAGS,
    OFFSET_ESTIMATE_TYPE_NAME, REJECT_MALFORMED, REJECT_REASONS, SIGNATURE_SAMPLE_TYPE_NAME,
    STATE_NONE, STATUS_TYPE_NAME,
};
use vlsync_common::{EstimatorState, Polarity, RejectReason};

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
  printf("%u %u %u %s %s %s\n", VLSYNC_FLAG_FIRST, VLSYNC_FLAG_SIMULATED, VLSYNC_KNOWN_FLAGS,
         VLSYNC_SIGNATURE_SAMPLE_TYPE_NAME, VLSYNC_OFFSET_ESTIMATE_TYPE_NAME, VLSYNC_STATUS_TYPE_NAME);
  printf("%d %d %d %d %d %d %d %d\n", VLSYNC_STATE_ACQUIRING, VLSYNC_STATE_TRACKING,
         VLSYNC_STATE_HOLDING, VLSYNC_STATE_LOST, VLSYNC_STATE_NONE, VLSYNC_POLARITY_UNKNOWN,
         VLSYNC_POLARITY_POSITIVE, VLSYNC_POLARITY_NEGATIVE);
  printf("%d %d %d %d %d %d\n", VLSYNC_REJECT_NON_FINITE, VLSYNC_REJECT_TOO_LARGE,
         VLSYNC_REJECT_BACKWARDS, VLSYNC_REJECT_REPEATED, VLSYNC_REJECT_MALFORMED,
         VLSYNC_REJECT_REASONS);
#if defined(VLSYNC_STATIC_ASSERT) || defined(VLSYNC_ALIGNOF)
  printf("the header's helper macros are left defined\n");
#endif
  return 0;
}
"#,
    )
    .unwrap();
    let exe = tmp.join("layout");
    vlsync_tests::compile(&src, &exe, false, &dir, &[]);
    let out = Command::new(&exe).output().unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    let mut expect = format!(
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
    expect += &format!(
        "{FLAG_FIRST} {FLAG_SIMULATED} {KNOWN_FLAGS} {SIGNATURE_SAMPLE_TYPE_NAME} {OFFSET_ESTIMATE_TYPE_NAME} \
         {STATUS_TYPE_NAME}\n"
    );
    let states = [
        EstimatorState::Acquiring,
        EstimatorState::Tracking,
        EstimatorState::Holding,
        EstimatorState::Lost,
    ]
    .map(|s| (s as u8).to_string());
    let polarities =
        [Polarity::Unknown, Polarity::Positive, Polarity::Negative].map(|p| (p as i8).to_string());
    expect += &format!(
        "{} {STATE_NONE} {}\n",
        states.join(" "),
        polarities.join(" ")
    );
    // the header's order: non-finite, too large, backwards, repeated
    let reasons = [
        RejectReason::NonFinite,
        RejectReason::TooLarge,
        RejectReason::Backwards,
        RejectReason::Repeated,
    ]
    .map(|r| r.index().to_string());
    expect += &format!(
        "{} {REJECT_MALFORMED} {REJECT_REASONS}\n",
        reasons.join(" ")
    );
    assert_eq!(text, expect);
    std::fs::remove_dir_all(&tmp).unwrap();
}
