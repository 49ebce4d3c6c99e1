#!/usr/bin/env python3
"""Unit tests of scripts/check-imports on small fixture crates.

    python3 scripts/check_imports_test.py
"""

import importlib.machinery
import importlib.util
import io
import os
import tempfile
import textwrap
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
_loader = importlib.machinery.SourceFileLoader(
    "check_imports", os.path.join(HERE, "check-imports")
)
_spec = importlib.util.spec_from_loader("check_imports", _loader)
check_imports = importlib.util.module_from_spec(_spec)
_loader.exec_module(check_imports)


class Fixture:
    """A crate `src/` folder in a temporary directory, from {relative path: text}."""

    def __init__(self, files):
        self.tmp = tempfile.TemporaryDirectory()
        self.src = os.path.join(self.tmp.name, "src")
        for relative, text in files.items():
            path = os.path.join(self.src, relative)
            os.makedirs(os.path.dirname(path), exist_ok=True)
            with open(path, "w", encoding="utf-8") as handle:
                text = textwrap.dedent(text)
                handle.write(text[1:] if text.startswith("\n") else text)

    def crate(self):
        return check_imports.Crate(self.src, "lib.rs")

    def edges(self):
        """{(from, to): sorted lines}, paths relative to src/."""
        return {
            (os.path.relpath(a, self.src), os.path.relpath(b, self.src)): sorted(set(lines))
            for (a, b), lines in self.crate().edges.items()
        }

    def run(self):
        out = io.StringIO()
        status = check_imports.main([self.src], out=out)
        return status, out.getvalue().replace(self.src + os.sep, "")

    def close(self):
        self.tmp.cleanup()


class FixtureTest(unittest.TestCase):
    def fixture(self, files):
        fixture = Fixture(files)
        self.addCleanup(fixture.close)
        return fixture


class Lexing(FixtureTest):
    def test_comments_and_literals_are_blanked_and_lines_kept(self):
        text = textwrap.dedent(
            """\
            // crate::line_comment
            /// [`crate::doc_link`]
            /* crate::block /* nested crate::inner */ still crate::comment */
            let a = "crate::string \\" crate::escaped";
            let b = r#"crate::raw "quoted" "#;
            let c = b"crate::bytes";
            let d = '"'; let e = '\\''; let f = b'x';
            fn g<'a>(x: &'a str) -> crate::kept::Item { crate::kept2::f() }
            """
        )
        stripped = check_imports.strip_comments_and_literals(text)
        self.assertEqual(stripped.count("\n"), text.count("\n"))
        self.assertNotIn("line_comment", stripped)
        self.assertNotIn("doc_link", stripped)
        self.assertNotIn("nested", stripped)
        self.assertNotIn("comment", stripped)
        self.assertNotIn("escaped", stripped)
        self.assertNotIn("raw", stripped)
        self.assertNotIn("bytes", stripped)
        self.assertIn("'a>(x: &'a str) -> crate::kept::Item { crate::kept2::f() }", stripped)
        self.assertEqual(stripped.splitlines()[7], text.splitlines()[7])


class Resolution(FixtureTest):
    def test_super_super_from_a_nested_file(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod a;\npub mod x;\n",
                "x.rs": "pub struct Thing;\n",
                "a/mod.rs": "pub mod b;\npub mod y;\n",
                "a/y.rs": "pub struct Thing;\n",
                "a/b.rs": "pub mod c;\n",
                "a/b/c.rs": "use super::super::y::Thing;\npub fn f() -> Thing { Thing }\n",
            }
        )
        self.assertEqual(fixture.edges(), {("a/b/c.rs", "a/y.rs"): [1]})

    def test_crate_path_inside_a_function_body(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod x;\npub mod user;\n",
                "x.rs": "pub fn helper() -> u8 { 1 }\n",
                "user.rs": "pub fn f() -> u8 {\n    let v = 2;\n    v + crate::x::helper()\n}\n",
            }
        )
        self.assertEqual(fixture.edges(), {("user.rs", "x.rs"): [3]})

    def test_nested_use_group(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod a;\npub mod x;\npub mod user;\n",
                "a/mod.rs": "pub mod b;\npub mod y;\n",
                "a/b.rs": "pub struct B;\n",
                "a/y.rs": "pub struct Y;\n",
                "x.rs": "pub struct X;\n",
                "user.rs": "use crate::{\n    a::{b::B, y::{self, Y}},\n    x::X,\n};\n",
            }
        )
        self.assertEqual(
            fixture.edges(),
            {("user.rs", "a/b.rs"): [2], ("user.rs", "a/y.rs"): [2], ("user.rs", "x.rs"): [3]},
        )

    def test_imported_module_name_in_code_and_self_paths(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod a;\npub mod user;\n",
                "a/mod.rs": "pub mod b;\n",
                "a/b.rs": "pub fn f() {}\n",
                "user.rs": "mod inner {\n    pub fn g() { crate::a::b::f() }\n}\n"
                "use crate::a;\npub fn h() {\n    a::b::f();\n    self::inner::g();\n}\n",
            }
        )
        self.assertEqual(fixture.edges(), {("user.rs", "a/b.rs"): [2, 6]})

    def test_inline_module_super_is_its_file(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod a;\npub mod b;\n",
                "a.rs": "pub struct A;\npub mod inner {\n    use super::A;\n    pub struct In(A);\n}\n",
                "b.rs": "use crate::a::inner::In;\n",
            }
        )
        self.assertEqual(fixture.edges(), {("b.rs", "a.rs"): [1]})

    def test_comments_strings_and_doc_links_are_not_edges(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod x;\npub mod user;\n",
                "x.rs": "pub struct X;\n",
                "user.rs": """
                    //! See [`crate::x::X`].
                    // use crate::x::X;
                    /* crate::x::X */
                    pub const S: &str = "crate::x::X";
                    pub const R: &str = r#"crate::x::X"#;
                    pub const C: char = '"';
                    pub fn f<'a>(s: &'a str) -> &'a str { s }
                    """,
            }
        )
        self.assertEqual(fixture.edges(), {})

    def test_cfg_test_modules_do_not_count(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod x;\npub mod y;\n#[cfg(test)]\nmod tests;\n",
                "tests.rs": "use crate::x::X;\n",
                "x.rs": "pub struct X;\npub fn f() -> crate::y::Y { crate::y::Y }\n",
                "y.rs": """
                    pub struct Y;
                    #[cfg(test)]
                    #[allow(unused)]
                    mod tests {
                        use super::*;
                        use crate::x::{f, X};
                        fn uses() { let _ = crate::x::f(); }
                    }
                    #[cfg(test)]
                    fn helper() -> crate::x::X { crate::x::X }
                    pub fn after() {}
                    """,
            }
        )
        self.assertEqual(fixture.edges(), {("x.rs", "y.rs"): [2]})
        status, _ = fixture.run()
        self.assertEqual(status, 0)

    def test_reexports_are_followed_to_the_defining_file(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod f;\npub mod types;\npub mod user;\npub use types::*;\n",
                "types.rs": "pub struct Config;\n",
                "f/mod.rs": "mod inner;\npub use inner::{Thing as Renamed, Other};\n"
                "pub use crate::types::Config as Shared;\n",
                "f/inner.rs": "pub struct Thing;\npub struct Other;\n",
                "user.rs": "use crate::f::Renamed;\npub fn c() -> crate::Config { crate::Config }\n"
                "pub fn o() -> crate::f::Other { crate::f::Other }\n",
            }
        )
        self.assertEqual(
            fixture.edges(),
            {
                ("user.rs", "f/inner.rs"): [1, 3],
                ("user.rs", "types.rs"): [2],
                ("f/mod.rs", "types.rs"): [3],
            },
        )

    def test_self_named_import_and_macro_crate_paths(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod x;\npub mod m;\n",
                "x.rs": "pub fn f() {}\n",
                "m.rs": "use serde;\nuse toml::toml;\n"
                "macro_rules! call {\n    () => { $crate::x::f() };\n}\n",
            }
        )
        self.assertEqual(fixture.edges(), {("m.rs", "x.rs"): [4]})


class Cycles(FixtureTest):
    def test_a_clean_tree_exits_0(self):
        fixture = self.fixture(
            {"lib.rs": "pub mod x;\npub mod y;\n", "x.rs": "", "y.rs": "use crate::x;\n"}
        )
        status, out = fixture.run()
        self.assertEqual(status, 0, out)
        self.assertIn("no import cycle", out)

    def test_file_cycle_with_lines(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod model;\npub mod modal;\npub mod tree;\n",
                "model.rs": "pub struct Model;\nfn t() { crate::tree::build(); }\n",
                "tree.rs": "use crate::modal::solve;\npub fn build() { solve() }\n",
                "modal.rs": "pub fn solve() {}\n\nuse crate::model::Model;\n",
            }
        )
        status, out = fixture.run()
        self.assertEqual(status, 1, out)
        self.assertIn("file cycle (3 files in the component): "
                      "modal.rs -> model.rs -> tree.rs -> modal.rs", out)
        self.assertIn("modal.rs:3 -> model.rs", out)
        self.assertIn("model.rs:2 -> tree.rs", out)
        self.assertIn("tree.rs:1 -> modal.rs", out)

    def test_a_parent_reexporting_a_child_is_no_cycle_but_using_it_is(self):
        reexport = {
            "lib.rs": "pub mod f;\n",
            "f/mod.rs": "mod child;\npub use child::run;\npub struct Shared;\n",
            "f/child.rs": "use super::Shared;\npub fn run() -> Shared { Shared }\n",
        }
        status, out = self.fixture(reexport).run()
        self.assertEqual(status, 0, out)
        uses = dict(reexport)
        uses["f/mod.rs"] += "pub fn go() { child::run(); }\n"
        status, out = self.fixture(uses).run()
        self.assertEqual(status, 1, out)
        self.assertIn("f/child.rs -> f/mod.rs -> f/child.rs", out)
        self.assertIn("f/mod.rs:4 -> f/child.rs", out)

    def test_a_sibling_reached_through_the_parents_reexport_is_a_cycle(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod f;\n",
                "f/mod.rs": "pub mod one;\npub mod two;\npub use two::Two;\n",
                "f/one.rs": "pub struct One;\nuse super::Two;\n",
                "f/two.rs": "pub struct Two;\npub fn g() -> super::one::One { todo!() }\n",
            }
        )
        status, out = fixture.run()
        self.assertEqual(status, 1, out)
        self.assertIn("f/one.rs -> f/two.rs -> f/one.rs", out)

    def test_folder_cycle_without_a_file_cycle(self):
        fixture = self.fixture(
            {
                "lib.rs": "pub mod analysis;\npub mod outputs;\n",
                "analysis/mod.rs": "pub mod monitor;\npub mod map;\n",
                "analysis/monitor.rs": "use crate::outputs::publisher::Publisher;\n",
                "analysis/map.rs": "pub struct Map;\n",
                "outputs/mod.rs": "pub mod publisher;\n",
                "outputs/publisher.rs": "pub struct Publisher;\nuse crate::analysis::map::Map;\n",
            }
        )
        status, out = fixture.run()
        self.assertEqual(status, 1, out)
        self.assertIn("0 file cycles, 1 folder cycles", out)
        self.assertIn("analysis/ -> outputs/ -> analysis/", out)
        self.assertIn("analysis/monitor.rs:1 -> outputs/publisher.rs", out)
        self.assertIn("outputs/publisher.rs:2 -> analysis/map.rs", out)


class Usage(FixtureTest):
    def test_missing_folder_or_root_or_module_file_exits_2(self):
        err = io.StringIO()
        with self.assertRaises(SystemExit) as raised:
            import contextlib

            with contextlib.redirect_stderr(err):
                check_imports.main(["/nonexistent/src"])
        self.assertEqual(raised.exception.code, 2)
        self.assertIn("/nonexistent/src: no such folder", err.getvalue())
        for files, message in [
            ({"other.rs": ""}, "neither lib.rs nor main.rs"),
            ({"lib.rs": "pub struct S;\npub mod gone;\n"}, "lib.rs:2: mod gone: neither"),
        ]:
            fixture = self.fixture(files)
            err = io.StringIO()
            import contextlib

            with contextlib.redirect_stderr(err):
                status = check_imports.main([fixture.src], out=io.StringIO())
            self.assertEqual(status, 2)
            self.assertIn(message, err.getvalue())


if __name__ == "__main__":
    unittest.main()
