//! vlsyncd library.
#![forbid(unsafe_code)]
