//! vlsync signature-level simulator with known truth, plus the tools to judge an
//! estimator against it.
//!
//! * [`families`]: deterministic scenarios ([`families::Family`]) producing camera and
//!   LiDAR signature streams and the true offset ([`families::generate`]);
//! * [`crb`]: the Cramér-Rao bound of the offset for a run (whole run and per window),
//!   and the causal bound of an ideal online estimator at given reference times
//!   ([`crb::causal_std_s`]; [`crb::share_beyond`], the share of errors it could not avoid);
//! * [`io`]: signature and truth CSV files (strict, line-numbered errors);
//! * [`baseline`]: the seed article's chunked correlator with its sign and lag-range bugs
//!   fixed — the number to beat;
//! * [`score`]: error statistics of estimator output against the truth.
//!
//! Clock convention (as in `vlsync_common`): `offset(t_L) = t_L - t_C`.
//!
//! ```
//! use vlsync_sim::{baseline, families::{generate, Family}, score};
//! let run = generate(Family::Seed, 3, None);
//! let s = score::score_pairs(&baseline::seed_chunked(&run.cam, &run.lidar, run.cam_hz), &run);
//! assert!(s.mae_s > run.crb_std_s); // the baseline is far from the bound
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod baseline;
pub mod crb;
pub mod families;
pub mod io;
pub mod score;

pub use families::{generate, try_generate, try_generate_with, Family, SimRun, Truth};
