//! millgate gateway library.

pub mod samples;
