//! The gateway's integration tests share the test kit (`millgate_tests::kit`, a
//! dev-dependency); this binds it to this package's `millgate` binary, which cargo
//! names for this package's tests only.
// Each test crate uses a part of it.
#![allow(dead_code, unused_imports)]

pub(crate) use millgate_tests::kit::*;

/// The `millgate` binary under test.
pub(crate) const MILLGATE: Millgate = Millgate(env!("CARGO_BIN_EXE_millgate"));

/// `millgate args`, run to its end (no standard input).
pub(crate) fn millgate(args: &[&str]) -> std::process::Output {
    MILLGATE.run(args)
}
