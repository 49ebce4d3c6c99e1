//! Shared fixtures for millgate's end-to-end tests.
