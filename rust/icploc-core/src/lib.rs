//! # icploc-core
//!
//! The pure-Rust core of icploc: 2D localization of a mobile robot by ICP matching of a
//! laser scan against a known map (Sa, Baek & Kuc; Besl & McKay). No Python here: the
//! `icploc-python` crate wraps this one.
//!
//! * [`se2`]: planar poses.
//! * [`index`]: [`MapIndex`], an immutable k-d tree over the map points with unit normals,
//!   nearest-neighbour queries and visibility culling.
//! * [`icp`]: the ICP loop: closest points, outlier rejection (distance threshold with an
//!   optional shrinking schedule, trimming, Huber/Cauchy weights), the Besl–McKay quaternion
//!   solve kept to a yaw, the point-to-line alternative, convergence rules, covariance and
//!   degeneracy from the Hessian of the final cost.
//! * [`likelihood`]: the likelihood grid and max-pooled pyramid of the correlative searches.
//! * [`quaternion`]: the closed-form registration of eq. 5–9 of the paper.
//! * [`fitscore`]: the verification evidence of a scan at a pose (hit share, residual).
//! * [`fusion`]: the covariance of a scan match (the localizer's measurement).
//! * [`noisegain`]: the odometry noise factor of one trusted scan pose (online noise).
//! * [`gridlines`]: wall lines (and leftover surface points) traced from occupancy grids.
//! * [`gridcast`]: occupancy grids from scans by ray casting (building maps from logs).
//! * [`raycast`]: ray casting against wall segments (simulation, visibility).
//! * [`scanprep`]: a laser scan's usable beams as robot-frame points.
//! * [`testkit`]: a deterministic office world and scan generator for tests and benchmarks.

// `!(x > 0.0)` is deliberate throughout: unlike `x <= 0.0` it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod error;
pub mod fitscore;
pub mod fusion;
pub mod global;
pub mod gridcast;
pub mod gridlines;
pub mod icp;
pub mod index;
pub mod likelihood;
pub mod noisegain;
pub mod quaternion;
pub mod raycast;
pub mod scanprep;
pub mod se2;
pub mod testkit;
pub mod text;

pub use error::{IcpError, Result};
pub use icp::{
    align, align_batch, Fit, IcpConfig, IcpResult, Metric, Robust, StartPath, Termination,
};
pub use index::MapIndex;
pub use se2::Pose2;

/// Check that every row of a point array is finite; name the input in the error.
pub fn check_finite(what: &str, pts: &[[f64; 2]]) -> Result<()> {
    match pts
        .iter()
        .position(|p| !(p[0].is_finite() && p[1].is_finite()))
    {
        Some(row) => Err(IcpError::NonFinite {
            what: what.to_string(),
            row,
        }),
        None => Ok(()),
    }
}
