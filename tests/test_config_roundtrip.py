"""The config stored in run.json can be loaded back into the same VOConfig."""
import json

from lite_vo.config import build_config, load_profile


def test_config_dict_round_trip_through_json():
    cfg = load_profile("board", ["tracking.huber=2.5"])
    again = build_config(json.loads(json.dumps(cfg.to_dict())), source="run.json")
    assert again == cfg
    assert again.name == "board" and again.tracking.huber == 2.5
