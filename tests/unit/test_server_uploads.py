"""Upload file names: what is kept for display, and RFC 5987 names."""

import pytest

from server.problems import Problem
from server.uploads import _extended_filename, check_file_name


@pytest.mark.parametrize(("given", "kept"), [
    ("bunny.ply", "bunny.ply"),
    ("C:\\scans\\bunny.ply", "bunny.ply"),
    ("../../etc/bunny.ply", "bunny.ply"),
    ("café.obj", "café.obj"),
    ("bun\x00ny\x1b[31m.ply", "bunny[31m.ply"),
    ("bunny\x85.ply", "bunny.ply"),  # a C1 control
    # U+202E makes 'bunny\u202egpj.ply' show as 'bunnyylp.jpg'.
    ("bunny\u202egpj.ply", "bunnygpj.ply"),
    ("a\u200bb.ply", "ab.ply"),  # zero-width space
    ("  spaced.ply  ", "spaced.ply"),
    ("\u202e", None),
    ("", None),
    (None, None),
])  # fmt: skip
def test_names_are_kept_as_shown_base_names(given, kept):
    assert check_file_name(given) == kept


@pytest.mark.parametrize(("given", "kept"), [
    ("..", None), (".", None), ("dir/..", None), ("a.", "a."), ("bunny.ply.txt", "bunny.ply.txt"),
])  # fmt: skip
def test_names_the_api_refuses_are_kept_from_a_multipart_body(given, kept):
    """``?name=`` follows the OpenAPI document's pattern (415 otherwise); a multipart file
    name, which the document cannot constrain, is kept (or dropped) for the record."""
    with pytest.raises(Problem):
        check_file_name(given)
    assert check_file_name(given, strict=False) == kept


def test_a_name_naming_an_unreadable_format_is_refused():
    with pytest.raises(Problem) as caught:
        check_file_name("photo.jpg")
    assert caught.value.status == 415


@pytest.mark.parametrize(("disposition", "name"), [
    (b"form-data; name=\"file\"; filename*=UTF-8''caf%C3%A9.ply", "café.ply"),
    (b"form-data; name=\"file\"; filename*=utf-8'en'a%20b.obj", "a b.obj"),
    (b"form-data; name=\"file\"; filename*=ISO-8859-1''caf%E9.ply", "café.ply"),
    (b"form-data; name=\"file\"; filename*=UTF-8''%FF.ply", "\ufffd.ply"),
    (b"form-data; name=\"file\"; filename*=koi8-r''x.ply", None),  # not an RFC 5987 charset
    (b"form-data; name=\"file\"", None),
])  # fmt: skip
def test_extended_file_names_are_decoded(disposition, name):
    assert _extended_filename(disposition) == name
