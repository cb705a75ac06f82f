//! One error type for the whole core. Every variant but `Internal` is the caller's input.

use thiserror::Error;

/// Everything that can go wrong in the core. The Python binding maps each variant to an
/// exception class (`InvalidInputError`, `EmptyMapError`, `GridTooLargeError`,
/// `InvalidConfigError`, all subclasses of `ValueError`).
#[derive(Debug, Error, Clone, PartialEq)]
pub enum IcpError {
    /// The map has no points.
    #[error("the map is empty: a MapIndex needs at least one point")]
    EmptyMap,
    /// An array has the wrong shape.
    #[error("{what}: expected {expected}, got {got}")]
    Shape {
        what: String,
        expected: String,
        got: String,
    },
    /// NaN or infinity where a finite number is required.
    #[error("{what}: non-finite value (NaN or inf) at row {row}")]
    NonFinite { what: String, row: usize },
    /// Fewer points than the algorithm needs.
    #[error("{what}: {got} points, need at least {min}")]
    TooFewPoints {
        what: String,
        got: usize,
        min: usize,
    },
    /// A configuration value out of range.
    #[error("invalid config: {field} = {value}: {reason}")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
    /// A grid (likelihood field, distance field) would need more cells than the core's
    /// memory bound: a coarser resolution (or a smaller map) is needed.
    #[error(
        "resolution: a {width:.1} m x {height:.1} m map at {resolution} m needs {cells} cells, \
         more than {max}"
    )]
    GridTooLarge {
        width: f64,
        height: f64,
        resolution: f64,
        cells: f64,
        max: usize,
    },
    /// Any other invalid input.
    #[error("{what}: {reason}")]
    InvalidInput { what: String, reason: String },
    /// A bug: something the core should never reach.
    #[error("internal error: {0}")]
    Internal(String),
}

/// Result alias of the core.
pub type Result<T> = std::result::Result<T, IcpError>;
