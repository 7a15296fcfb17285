import numpy as np
from lightstage_physics.rig import Rig
from lightstage_physics.scene_models import ModelSet


def make_modelset(n_per_class=2, size=24, n_classes=2, seed=0):
    rng = np.random.default_rng(seed)
    n = n_per_class * n_classes
    models = rng.uniform(0, 200, size=(n, 4, 8, size, size)).astype(np.float32)
    labels = np.repeat(np.arange(n_classes), n_per_class)
    class_names = [f"fruit{k}-{'fake' if k % 2 else 'real'}" for k in range(n_classes)]
    pose = np.tile(np.arange(n_per_class), n_classes)
    inst = pose // 2
    names = [f"{class_names[lab]}/s{i}/p{p:02d}" for lab, i, p in zip(labels, inst, pose)]
    return ModelSet(models, labels, class_names, names, pose, inst, Rig.paper_default(size))

