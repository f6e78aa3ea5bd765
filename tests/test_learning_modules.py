"""``pointfield.classify`` and ``pointfield.segment`` are modules: ``import pointfield.classify``
works in a fresh interpreter, as ``import pointfield`` then ``pointfield.classify`` does."""

from __future__ import annotations

import subprocess
import sys

import pointfield
from pointfield.clouds import synthetic


def test_import_pointfield_classify_and_segment_in_a_fresh_interpreter(checkout_environment):
    code = (
        "import pointfield.classify, pointfield.segment\n"
        "from pointfield.segment import predict\n"
        "print(pointfield.classify.train.__module__, pointfield.segment.evaluate.__module__, predict.__module__)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=checkout_environment,
                            check=False)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["pointfield.classify", "pointfield.segment", "pointfield.segment"]


def test_the_package_attribute_is_the_module():
    import pointfield.classify

    assert pointfield.classify is sys.modules["pointfield.classify"]
    assert pointfield.segment is sys.modules["pointfield.segment"]


def test_each_module_trains_its_own_task(tmp_path, one_torch_thread):
    from pointfield import classify

    metrics = classify.train(out=tmp_path / "shapes", epochs=1, points=32, shapes_per_class=2, batch_size=8,
                             device="cpu", progress=False)
    assert "accuracy" in metrics
    assert pointfield.load_run(tmp_path / "shapes").config["task"] == "classify"
    pointfield.write(tmp_path / "ball.ply", synthetic.sphere(count=200, seed=0))
    (answer,) = classify.predict(tmp_path / "shapes", [tmp_path / "ball.ply"], device="cpu")
    assert answer["class"] in pointfield.load_run(tmp_path / "shapes").config["classes"]
