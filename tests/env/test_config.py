import json
import re

import numpy as np
import pytest

from catmip_env import PRESETS, EnvConfig, RobotClass, make_config


def test_presets_match_the_paper():
    t1, t2, t3, tr = (PRESETS[k] for k in ("task1", "task2", "task3", "train"))
    assert (t1.map_size, t1.num_robots, t1.horizon_ticks) == (15, 2, 300)
    assert (t2.map_size, t2.num_robots, t2.horizon_ticks) == (20, 3, 400)
    assert (t3.map_size, t3.num_robots, t3.horizon_ticks) == (32, 6, 500)
    assert t3.team.count("rescuer") == 2 and t3.team.count("explorer") == 4
    assert (tr.map_size, tr.horizon_ticks, tr.team) == (20, 200, ("rescuer", "explorer", "random"))
    assert [PRESETS[k].obstacles for k in ("task1", "task2", "task3")] == [5, 10, 25]


def test_default_classes():
    cfg = EnvConfig()
    rescuer = cfg.classes[cfg.class_index("rescuer")]
    explorer = cfg.classes[cfg.class_index("explorer")]
    assert rescuer.ticks_per_action == 2 and rescuer.can_rescue
    assert explorer.ticks_per_action == 1 and not explorer.can_rescue


@pytest.mark.parametrize(
    "overrides, needle",
    [
        ({"map_size": 8}, "map_size"),
        ({"team": ("rescuer",) * 17}, "spawn box"),
        ({"team": ("rescuer", "medic")}, "unknown class name 'medic'"),
        ({"slam_noise": -0.1}, "slam_noise"),
        ({"slam_noise": 1.5}, "slam_noise"),
        ({"wall_prob": -0.5}, "wall_prob"),
        ({"comm_sigma": 0.0}, "comm_sigma"),
        ({"comm_sigma": -2.0}, "comm_sigma"),
        ({"horizon_ticks": 0}, "horizon_ticks"),
        ({"num_obstacles": -1}, "num_obstacles"),
        ({"num_obstacles": 10_000}, "too many"),
        ({"local_size": 6}, "local_size"),
        ({"window": 4}, "window"),
        ({"team": ()}, "at least one robot"),
        ({"team": ("random",), "random_classes": ("ghost",)}, "random_classes"),
        # values of the wrong type (JSON from the CLI's --set) are named, never a TypeError
        ({"map_size": 100_000}, r"map_size must be an int in \[10, 512\]"),
        ({"map_size": 15.0}, "map_size must be an int"),
        # a count past int64 would fail in the compiled kernels, not in one line
        ({"max_ma_ticks": 10**20}, r"max_ma_ticks must be an int in \[1, 1000000\]"),
        ({"horizon_ticks": 10**10}, r"horizon_ticks must be an int in \[1, 1000000\]"),
        ({"window": True}, "window must be an int"),
        ({"team": "rescuer"}, "team must be a list of class names, got 'rescuer'"),
        ({"team": [1, 2]}, "team must be a list of class names"),
        ({"random_classes": "rescuer"}, "random_classes must be a list"),
        ({"layout": ["#####", "#...#", "#####"]}, "layout must be None or one string"),
        ({"layout": 5}, "layout must be None or one string"),
        ({"comm_sigma": "abc"}, "comm_sigma must be None .* finite number"),
        ({"comm_sigma": float("inf")}, "comm_sigma"),
        ({"comm_sigma": float("nan")}, "comm_sigma must be None .* finite number"),
        # tiny but positive: 1/sigma^2 would divide by zero in the link kernel
        ({"comm_sigma": 1e-300}, r"comm_sigma must be .* >= 0\.01 \(cells\), got 1e-300"),
        ({"comm_sigma": 0.009}, r"comm_sigma .* >= 0\.01 .*, got 0\.009"),
        ({"wall_prob": "x"}, "wall_prob must be a finite number"),
        ({"slam_noise": float("nan")}, "slam_noise must be a finite number"),
        ({"step_reward": "x"}, "step_reward must be a finite number"),
        ({"find_reward": True}, "find_reward must be a finite number"),
        ({"synchronous": "yes"}, "synchronous must be true or false"),
        ({"num_obstacles": 1.5}, "num_obstacles must be None or an int"),
        ({"activation": 5}, "activation must be a list of two ints"),
        ({"activation": [1, "a"]}, "activation must be"),
        ({"classes": 5}, "classes must be a list of robot classes"),
        ({"classes": [5]}, "classes: a robot class must be"),
        ({"classes": [{"nom": "x"}]}, r"classes: .*unknown: \['nom'\]"),
        (
            {"classes": [{"name": "x", "can_rescue": "yes"}], "team": ["x"]},
            "can_rescue must be true or false",
        ),
    ],
)
def test_bad_config_values_raise_clear_errors(overrides, needle):
    with pytest.raises(ValueError, match=needle):
        EnvConfig().replace(**overrides)


def test_valid_values_of_any_spelling_still_work():
    """JSON ints for floats, lists for tuples, numpy floats, dicts for classes: accepted as before."""
    classes = [{"name": "rescuer", "ticks_per_action": 2, "can_rescue": True}, {"name": "explorer"}]
    cfg = EnvConfig().replace(
        comm_sigma=4,
        slam_noise=np.float64(0.05),
        team=["rescuer", "explorer"],
        activation=[2, 5],
        classes=classes,
    )
    assert cfg.team == ("rescuer", "explorer") and cfg.activation == (2, 5) and cfg.comm_sigma == 4
    assert cfg.classes == EnvConfig().classes and EnvConfig.from_dict(json.loads(cfg.to_json())) == cfg
    assert EnvConfig().replace(map_size=512).map_size == 512
    with pytest.raises(ValueError, match="JSON object"):
        EnvConfig.from_dict(None)


# hand-drawn layouts whose target some robot cannot reach: walls and obstacles block, robots and clues do not
SEALED = """
#########
#0..#...#
#...#.T.#
#1..#...#
#########
"""
BEHIND_OBSTACLES = """
#########
#0......#
#....o..#
#...oTo.#
#1...o..#
#########
"""
ONLY_DIAGONAL = """
#######
#0....#
#..#..#
#.#T#.#
#..#..#
#1....#
#######
"""
ONE_WALLED_IN = """
##########
#0.......#
#.....T..#
####.....#
#1.#.....#
##########
"""
# reachable: through a doorway, past a robot standing in it, over the clues around the target
THROUGH_A_DOOR = """
#########
#0..#...#
#...1.T.#
#...#...#
#########
"""


@pytest.mark.parametrize(
    "layout, target, cut_off",
    [(SEALED, (2, 6), [0, 1]), (BEHIND_OBSTACLES, (3, 5), [0, 1]), (ONLY_DIAGONAL, (3, 3), [0, 1]),
     (ONE_WALLED_IN, (2, 6), [1])],
)  # fmt: skip
def test_a_layout_whose_target_a_robot_cannot_reach_is_refused(layout, target, cut_off):
    wanted = f"layout target {target} is unreachable from the start of robot(s) {cut_off}: walls and"
    with pytest.raises(ValueError, match=re.escape(wanted)):
        EnvConfig(layout=layout, team=("rescuer", "explorer"))
    assert EnvConfig(layout=THROUGH_A_DOOR, team=("rescuer", "explorer")).map_shape == (5, 9)


def test_bad_robot_class_and_unknown_fields():
    with pytest.raises(ValueError, match="ticks_per_action"):
        RobotClass("slow", ticks_per_action=0)
    with pytest.raises(ValueError, match="unknown EnvConfig field"):
        make_config("task1", comm_range=3)
    with pytest.raises(ValueError, match="unknown preset"):
        make_config("task9")
    with pytest.raises(ValueError, match="unique"):
        EnvConfig(classes=(RobotClass("a"), RobotClass("a")), team=("a",))


def test_overrides_and_json_roundtrip():
    cfg = make_config("task2", comm_sigma=4.0, slam_noise=0.05, horizon_ticks=123)
    assert cfg.comm_sigma == 4.0 and cfg.slam_noise == 0.05 and cfg.horizon_ticks == 123
    assert PRESETS["task2"].comm_sigma is None  # presets are not mutated
    back = EnvConfig.from_dict(json.loads(cfg.to_json()))
    assert back == cfg


def test_custom_classes_are_data():
    drone = RobotClass("drone", ticks_per_action=1)
    medic = RobotClass("medic", ticks_per_action=3, can_rescue=True)
    tank = RobotClass("tank", ticks_per_action=4)
    cfg = EnvConfig(classes=(drone, medic, tank), team=("medic", "drone", "tank"))
    assert cfg.num_classes == 3 and cfg.class_index("tank") == 2
