//! Text quoted in error messages.

/// Most characters of an input value quoted in an error.
pub const CLIP_CHARS: usize = 40;

/// `s` as an error quotes it: cut at [`CLIP_CHARS`] characters with an ellipsis, so
/// a megabyte of garbage in one field does not become a megabyte of error.
///
/// ```
/// use vlsync_common::text::clip;
/// assert_eq!(clip("1.5x"), "1.5x");
/// assert_eq!(clip(&"9".repeat(100)), format!("{}…", "9".repeat(40)));
/// ```
pub fn clip(s: &str) -> String {
    if s.chars().count() > CLIP_CHARS {
        let mut c: String = s.chars().take(CLIP_CHARS).collect();
        c.push('…');
        c
    } else {
        s.to_string()
    }
}
