"""Mitsuba's `moment` integrator (the wrapper of Mitsuba's render tests): the tracer renders the integrator
nested inside it, whose image is the moment's image, and refuses a moment it cannot honour in one line."""
import numpy as np
import pytest

from tracer import cli, load_scene, render

from .test_xml_features import scene_errors
from .test_xml_loader import assert_located, line_of, write_scene

LIT = """<shape type="sphere"><point name="center" x="0" y="0" z="5"/><float name="radius" value="1"/>
    <emitter type="area"><rgb name="radiance" value="1, 2, 3"/></emitter></shape>
<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="180"/><scale value="5"/>
    <translate z="8"/></transform></shape>
"""
PATH = '<integrator type="path"><integer name="max_depth" value="3"/><integer name="rr_depth" value="2"/></integrator>'


def _moment(inner: str, extra: str = "") -> str:
    return f'<integrator type="moment">{extra}\n{inner}</integrator>'


def test_moment_renders_its_nested_integrator_bit_for_bit(tmp_path):
    plain = load_scene(write_scene(tmp_path, PATH + LIT, "path.xml"))
    wrapped = load_scene(write_scene(tmp_path, _moment(PATH) + LIT, "moment.xml"))
    assert (wrapped.max_depth, wrapped.rr_depth) == (plain.max_depth, plain.rr_depth) == (3, 2)
    assert (plain.integrator, wrapped.integrator) == ("path", "moment around path")
    a = render(plain, spp=4, seed=1).image
    b = render(wrapped, spp=4, seed=1).image
    assert a.max() > 0 and np.array_equal(a, b)


def test_nested_integrator_given_by_parameter_as_in_mitsubas_tests(tmp_path):
    body = ('<default name="integrator" value="path"/>'
            '<integrator type="moment"><integrator type="$integrator"><integer name="max_depth" value="2"/>'
            '</integrator></integrator>' + LIT)
    path = write_scene(tmp_path, body)
    assert load_scene(path).max_depth == 2
    (error,) = scene_errors(path, integrator="prbvolpath")
    assert "unsupported integrator plugin 'prbvolpath'" in error


@pytest.mark.parametrize("body, snippet, words", [
    ('<integrator type="moment">\n</integrator>', 'type="moment"', "with 0 nested integrators"),
    (_moment(PATH + PATH), 'type="moment"', "with 2 nested integrators"),
    (_moment(PATH, '<boolean name="hide_emitters" value="true"/>'), "hide_emitters",
     "hide_emitters = true is not supported"),
    (_moment(PATH, '<float name="timeout" value="2"/>'), "timeout", "'timeout' is not supported"),
    (_moment(PATH, '<integer name="max_depth" value="7"/>'), 'value="7"/>', "unreferenced property 'max_depth'"),
    (_moment('<integrator type="stokes"/>'), 'type="stokes"', "unsupported integrator plugin 'stokes'"),
    (_moment(PATH, '<sensor type="perspective"/>'), '<sensor type="perspective"/>', "is unsupported"),
])
def test_a_moment_the_tracer_cannot_honour_is_refused_in_one_line(tmp_path, body, snippet, words):
    path = write_scene(tmp_path, body + LIT)
    errors = scene_errors(path)
    assert len(errors) == 1 and words in errors[0], errors
    assert_located(errors[0], path, line_of(path, snippet))


def test_info_says_what_a_moment_renders(tmp_path, capsys):
    path = write_scene(tmp_path, _moment(PATH) + LIT)
    assert cli.main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "integrator: moment around path, max_depth 3, rr_depth 2" in out
    assert "renders the nested integrator's image" in out
