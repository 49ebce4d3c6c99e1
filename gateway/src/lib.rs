//! millgate gateway library.
