"""MJCF snippets: a model around a worldbody's contents, two welded planar arms, a two-joint arm, and models
nested to any depth."""

from __future__ import annotations

HEAD = '<compiler boundmass="1" boundinertia="0.1"/>'  # masses MuJoCo needs; no kinematic effect


def mjcf(body: str, head: str = "", tail: str = "") -> str:
    """A ``<mujoco>`` model around a worldbody's contents."""
    return f"<mujoco model='m'>{HEAD}{head}<worldbody>{body}</worldbody>{tail}</mujoco>"


# Two planar arms from the ground, welded at their tips: 3 + 2 hinges, 3 planar equations; a1 and b1 driven.
WELDED_ARMS = mjcf(
    '<body name="a1"><joint name="a1" axis="0 0 1"/><geom size=".01" mass=".1"/>'
    '<body name="a2" pos=".3 0 0"><joint name="a2" axis="0 0 1"/><geom size=".01" mass=".1"/>'
    '<body name="a3" pos=".3 0 0"><joint name="a3" axis="0 0 1"/><geom size=".01" mass=".1"/></body></body></body>'
    '<body name="b1" pos=".8 0 0"><joint name="b1" axis="0 0 1"/><geom size=".01" mass=".1"/>'
    '<body name="b2" pos="-.2 .1 0" euler="0 0 30"><joint name="b2" axis="0 0 1"/><geom size=".01" mass=".1"/>'
    "</body></body>",
    tail='<equality><weld body1="a3" body2="b2"{relpose}/></equality>'
    '<actuator><motor joint="a1"/><motor joint="b1"/></actuator>',
)


ARM = (
    '<geom size=".01"/><joint name="a" axis="1 2 3" pos=".1 0 .2" range="-90 45"/>'
    '<body name="b" pos="0 .3 0" {o}><joint name="b" axis="0 1 0" range="-1 1"/><site name="s" pos=".1 .2 .3" {o}/>'
    "</body>"
)


def nested_mjcf(kind: str, depth: int) -> str:
    """A model nested ``depth`` deep in ``kind``.

    ``bodies``: a chain of bodies (each ``pos="0 0 .01" euler="0 0 3"`` and a hinge, a site ``tip``
    in the last), then a top-level body ``side``. ``frames``: ``<frame>``s with that offset around a
    site ``tip`` and a body ``c``. ``default_classes``: classes ``c0 ... c{depth-1}`` (``c0`` sets
    the joint axis to y, ``c{depth // 2}`` a range of -30..60 degrees) used by the joints ``j``
    (innermost class, as ``childclass``) and ``k`` (the class above ``c{depth // 2}``).
    """
    step = 'pos="0 0 .01" euler="0 0 3"'
    head = ""
    if kind == "bodies":
        body = "".join(f'<body name="b{k}" {step}><joint name="j{k}" axis="1 0 0" range="-1 1"/>' for k in range(depth))
        body += '<site name="tip" pos="0 0 .5"/>' + "</body>" * depth + '<body name="side"><joint name="s"/></body>'
    elif kind == "frames":
        body = (
            '<body name="b"><joint name="j" axis="1 0 0"/>'
            + f"<frame {step}>" * depth
            + '<site name="tip"/><body name="c"><joint name="k" axis="0 1 0"/></body>'
            + "</frame>" * depth
            + "</body>"
        )
    else:
        joint = {0: '<joint axis="0 1 0"/>', depth // 2: '<joint range="-30 60"/>'}
        head = "<default>" + "".join(f'<default class="c{k}">{joint.get(k, "")}' for k in range(depth))
        head += "</default>" * (depth + 1)
        body = (
            f'<body name="b" childclass="c{depth - 1}"><joint name="j"/>'
            f'<body name="c"><joint name="k" class="c{depth // 2 - 1}"/></body></body>'
        )
    return mjcf(body, head)
