//! evcore: the pure-Rust core of evservo (no Python here).
//!
//! Data walks one way: raw events ([`event`]) are rectified through [`camera::UndistortLut`] into a
//! front-end ([`surface`]: SCARF, fixed-count, EROS); its active set becomes a truncated event
//! distance field ([`field`]); a model point set rendered once ([`render`], [`pointset`]) is
//! registered to the field by the solvers ([`solve`]); [`tracker`] runs that loop in its own thread.
//! [`sim`] is the event-camera simulator and [`io`] decodes recorded event streams.

pub mod camera;
pub mod clock;
pub mod confidence;
pub mod error;
pub mod event;
pub mod field;
pub mod freshness;
pub mod image;
pub mod io;
pub mod latency;
pub mod mesh;
pub mod pointset;
mod prefetch;
pub mod render;
pub mod replay;
pub mod rng;
pub mod se3;
pub mod sim;
pub mod solve;
pub mod surface;
pub mod templates;
pub mod tracker;

pub use camera::{Camera, UndistortLut};
pub use error::{Error, Result};
pub use event::{EventBatch, EventCd, EventRecords};
pub use image::Roi;
pub use se3::Pose;
pub use surface::{
    make_surface, split_surface, EventSurface, FrontEnd, SurfaceReader, SurfaceWriter,
};
