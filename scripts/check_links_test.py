#!/usr/bin/env python3
"""Unit tests of scripts/check-links on small fixture repositories.

    python3 scripts/check_links_test.py
"""

import importlib.machinery
import importlib.util
import io
import os
import subprocess
import tempfile
import textwrap
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
_loader = importlib.machinery.SourceFileLoader("check_links", os.path.join(HERE, "check-links"))
_spec = importlib.util.spec_from_loader("check_links", _loader)
check_links = importlib.util.module_from_spec(_spec)
_loader.exec_module(check_links)


class Fixture:
    """A repository in a temporary folder, from {relative path: text}; git when asked."""

    def __init__(self, files, git=False, untracked=()):
        self.tmp = tempfile.TemporaryDirectory()
        self.root = self.tmp.name
        for relative, text in files.items():
            self.write(relative, text)
        if git:
            subprocess.run(["git", "init", "-q", self.root], check=True)
            subprocess.run(["git", "-C", self.root, "add", "-A"], check=True)
        for relative in untracked:
            self.write(relative, "")

    def write(self, relative, text):
        path = os.path.join(self.root, relative)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w", encoding="utf-8") as handle:
            text = textwrap.dedent(text)
            handle.write(text[1:] if text.startswith("\n") else text)

    def run(self, *files):
        out = io.StringIO()
        status = check_links.main(["--root", self.root, *files], out=out)
        return status, out.getvalue()

    def close(self):
        self.tmp.cleanup()


class FixtureTest(unittest.TestCase):
    def fixture(self, files, **options):
        fixture = Fixture(files, **options)
        self.addCleanup(fixture.close)
        return fixture

    def broken(self, files, **options):
        """The broken-link lines of a fixture's run (status 1 asserted when any)."""
        status, out = self.fixture(files, **options).run()
        lines = [line for line in out.splitlines() if not line.startswith("check-links:")]
        self.assertEqual(status, 1 if lines else 0, out)
        return lines


class Slugs(unittest.TestCase):
    def test_github_rule(self):
        cases = {
            "Usage": "usage",
            "Running under systemd": "running-under-systemd",
            "Captures: the samples behind each verdict": "captures-the-samples-behind-each-verdict",
            "The closed loop's plant": "the-closed-loops-plant",
            "Rod mills (`rod`)": "rod-mills-rod",
            "Checks (`cargo test -p millgate-sim --test tandem`)": "checks-cargo-test--p-millgate-sim---test-tandem",
            "Table 3 identified: `rsm-table3.toml`": "table-3-identified-rsm-table3toml",
            "`[[sources.modbus]]`: Modbus devices": "sourcesmodbus-modbus-devices",
            "**Bold** and *emphasis*": "bold-and-emphasis",
            "A [link](x.md) inside": "a-link-inside",
            "`first_period_s` in code": "first_period_s-in-code",
            "OPC UA": "opc-ua",
            "Größe & Maß": "größe--maß",
            "Status <sup>1</sup>": "status-1",
        }
        for heading, slug in cases.items():
            with self.subTest(heading=heading):
                self.assertEqual(check_links.slugify(heading), slug)


class Links(FixtureTest):
    def test_working_links_pass(self):
        lines = self.broken(
            {
                "README.md": """
                # Title

                See [usage](docs/usage.md), [its exit status](docs/usage.md#exit-status),
                [the top](#title), ![a picture](docs/img/a.svg), the
                [examples](config/examples/) and [a line](src/lib.rs#L3-L5).
                A link whose text wraps [over
                two lines](docs/usage.md) and one in angle brackets [x](<docs/usage.md>).
                [ref]: docs/usage.md
                Use [the reference][ref] and <https://example.com/a?b=c>.
                <img src="docs/img/a.svg" alt="">
                """,
                "docs/usage.md": """
                # Usage

                ## Exit status

                Back to the [front door](../README.md#title).
                """,
                "docs/img/a.svg": "<svg/>",
                "config/examples/demo.toml": "",
                "src/lib.rs": "",
            }
        )
        self.assertEqual(lines, [])

    def test_a_missing_file_is_reported_with_its_line(self):
        lines = self.broken(
            {
                "README.md": """
                # Title

                One [gone](docs/gone.md) link.
                """
            }
        )
        self.assertEqual(lines, ["README.md:3: 'docs/gone.md': no file docs/gone.md"])

    def test_a_missing_anchor_is_reported(self):
        lines = self.broken(
            {
                "README.md": "# Title\n\n[x](docs/a.md#nowhere) and [y](#title-2)\n",
                "docs/a.md": "# A\n",
            }
        )
        self.assertEqual(
            lines,
            [
                "README.md:3: 'docs/a.md#nowhere': no heading in docs/a.md has the anchor #nowhere",
                "README.md:3: '#title-2': no heading in README.md has the anchor #title-2",
            ],
        )

    def test_an_upper_case_anchor_is_reported(self):
        lines = self.broken({"README.md": "# Two Words\n\n[x](#Two-Words)\n"})
        self.assertEqual(lines, ["README.md:3: '#Two-Words': write the anchor lower case: #two-words"])

    def test_repeated_headings_are_numbered(self):
        lines = self.broken(
            {"a.md": "# A\n## Notes\n## Notes\n## Notes\n[1](#notes) [2](#notes-1) [3](#notes-2) [4](#notes-3)\n"}
        )
        self.assertEqual(lines, ["a.md:5: '#notes-3': no heading in a.md has the anchor #notes-3"])

    def test_setext_headings_and_html_ids_are_anchors(self):
        lines = self.broken(
            {"a.md": "Setext title\n============\n\n<a id=\"here\"></a>\n[1](#setext-title) [2](#here)\n"}
        )
        self.assertEqual(lines, [])

    def test_code_is_not_read_for_links_or_headings(self):
        lines = self.broken(
            {
                "a.md": """
                # Real

                ```sh
                # not a heading
                echo [x](gone.md)
                ```

                Inline `[y](gone.md)` and a span ``over
                two [z](gone.md) lines``; <!-- [c](gone.md) -->
                [w](#not-a-heading)
                """
            }
        )
        self.assertEqual(lines, ["a.md:10: '#not-a-heading': no heading in a.md has the anchor #not-a-heading"])

    def test_an_anchor_into_a_file_that_is_not_markdown(self):
        lines = self.broken({"a.md": "[x](b.rs#L10) [y](b.rs#main)\n", "b.rs": ""})
        self.assertEqual(
            lines,
            ["a.md:1: 'b.rs#main': an anchor into b.rs, which is no Markdown file (only #L<line> works there)"],
        )

    def test_external_links_must_be_well_formed(self):
        lines = self.broken(
            {
                "a.md": "[a](https://example.com/x) [b](http:/example.com) [c](https://) "
                "[d](ftp://example.com) [e](mailto:someone@example.com) [f](mailto:nobody)\n"
            }
        )
        self.assertEqual(
            lines,
            [
                "a.md:1: 'http:/example.com': a web link without a well-formed host",
                "a.md:1: 'https://': a web link without a well-formed host",
                "a.md:1: 'ftp://example.com': an unknown scheme 'ftp:'",
                "a.md:1: 'mailto:nobody': a mailto: without an address",
            ],
        )

    def test_links_outside_the_repository_and_folder_links(self):
        lines = self.broken({"a.md": "[a](../elsewhere.md) [b](b.md/) [c](b.md)\n", "b.md": ""})
        self.assertEqual(
            lines,
            [
                "a.md:1: '../elsewhere.md': outside the repository",
                "a.md:1: 'b.md/': b.md is a file, not a folder",
            ],
        )

    def test_undefined_reference(self):
        lines = self.broken({"a.md": "[text][nowhere] and [text][Here]\n\n[here]: a.md\n"})
        self.assertEqual(lines, ["a.md:1: 'nowhere': a reference to an undefined label"])

    def test_rust_paths_are_left_to_rustdoc_in_crate_docs_only(self):
        files = {
            "crate/README.md": "[catalogue](state::catalogue) [x](gone.md)\n",
            "crate/src/lib.rs": '#![doc = include_str!("../README.md")]\n',
            "docs/a.md": "[catalogue](state::catalogue)\n",
        }
        lines = self.broken(files)
        self.assertEqual(
            lines,
            [
                "crate/README.md:1: 'gone.md': no file crate/gone.md",
                "docs/a.md:1: 'state::catalogue': an unknown scheme 'state:'",
            ],
        )

    def test_in_git_only_tracked_files_count(self):
        lines = self.broken(
            {"a.md": "[a](tracked.txt) [b](local.txt)\n", "tracked.txt": ""},
            git=True,
            untracked=["local.txt"],
        )
        self.assertEqual(lines, ["a.md:1: 'local.txt': local.txt is not tracked by git"])

    def test_named_files_only_and_a_missing_one_is_a_usage_error(self):
        fixture = self.fixture({"a.md": "[x](gone.md)\n", "b.md": "fine\n"})
        self.assertEqual(fixture.run("b.md")[0], 0)
        with self.assertRaises(SystemExit) as exit:
            with open(os.devnull, "w") as devnull:
                import contextlib

                with contextlib.redirect_stderr(devnull):
                    fixture.run("c.md")
        self.assertEqual(exit.exception.code, 2)

    def test_the_summary_counts_links_and_files(self):
        status, out = self.fixture({"a.md": "[x](b.md)\n", "b.md": "[y](a.md) [z](gone.md)\n"}).run()
        self.assertEqual(status, 1)
        self.assertTrue(out.endswith("check-links: 1 broken of 3 links in 2 files\n"), out)


if __name__ == "__main__":
    unittest.main()
