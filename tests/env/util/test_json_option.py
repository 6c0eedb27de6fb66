"""``json_object_option``: the one parser of the JSON-object command-line options (--dagger-options,
--demo-config, demos --config / --env)."""
import pytest

from wt_inspect_env.util.validation import json_object_option


def test_inline_file_and_empty(tmp_path):
    assert json_object_option("--x", None) == {} and json_object_option("--x", "") == {}
    assert json_object_option("--x", ' {"a": [1, 2]} ') == {"a": [1, 2]}
    f = tmp_path / "o.json"
    f.write_text('{"rounds": 3}')
    assert json_object_option("--x", str(f)) == {"rounds": 3}


@pytest.mark.parametrize("text, match", [
    ("{nope", "--x is not valid JSON"),
    ("[1, 2]", "--x must be a JSON object, got '\\[1, 2\\]'"),
    ("missing.json", "--x file 'missing.json' not found"),
])
def test_bad_text_is_one_line_naming_the_option(text, match):
    with pytest.raises(ValueError, match=match) as e:
        json_object_option("--x", text)
    assert "\n" not in str(e.value)
