"""PNG figures of an evaluation: accuracy vs image count and the selected pattern matrices."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt
import numpy as np

STYLE = {'greedy': ('-', 'o'), 'snr_optimal': ('--', 's'), 'greedy_joint': (':', '^'),
         'learned': ('-.', 'D')}


def plot_accuracy_vs_images(doc: dict, path, by: str = 'columns') -> Path:
    """Held-out accuracy vs image count: greedy solid, SNR-optimal dashed, joint greedy
    dotted, one colour per noise setting; naive methods as horizontal reference lines.

    by: 'columns' (pattern columns, the paper's figure; a per-colour column is 4 exposures)
    or 'exposures' (camera exposures, which puts the joint 32-LED mode, one exposure per
    column, on the same axis as the paper's per-colour mode).
    """
    if by not in ('columns', 'exposures'):
        raise ValueError(f"by must be 'columns' or 'exposures', got {by!r}")
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    colours = plt.rcParams['axes.prop_cycle'].by_key()['color']
    for i, (noise, r) in enumerate(doc['by_noise'].items()):
        colour = colours[i % len(colours)]
        for name, m in r['methods'].items():
            acc = m['accuracy_by_images']
            if name in STYLE:
                ks = sorted(int(k) for k in acc)
                per = int(m.get('images_per_pattern', 1)) if by == 'exposures' else 1
                ax.plot([k * per for k in ks], [100 * acc[str(k)] for k in ks],
                        linestyle=STYLE[name][0], marker=STYLE[name][1], color=colour,
                        label=f'{name} {noise}')
            elif i == 0:
                ax.axhline(100 * m['accuracy'], color='gray', linewidth=0.8,
                           linestyle='-.' if name == 'naive_bow' else ':')
                ax.annotate(f'{name} {noise}', (1, 100 * m['accuracy']), fontsize=7,
                            color='gray', va='bottom')
    ax.set_xlabel('image count (pattern columns; per colour: 4 exposures each)'
                  if by == 'columns' else 'camera exposures')
    ax.set_ylabel('held-out accuracy %')
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_pattern_matrices(doc: dict, path) -> Path:
    """Like the paper's figure of patterns: one panel per (method, noise), rows = sites or
    LEDs, columns = images, lit = white; columns that did not improve accuracy are shaded."""
    panels = [(name, noise, m) for noise, r in doc['by_noise'].items()
              for name, m in r['methods'].items() if name in STYLE]
    if not panels:
        panels = [(name, noise, m) for noise, r in doc['by_noise'].items()
                  for name, m in r['methods'].items()]
    n = len(panels)
    ncol = min(3, n)
    nrow = int(np.ceil(n / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.2 * ncol, 2.8 * nrow), squeeze=False)
    for ax in axes.ravel():
        ax.axis('off')
    for ax, (name, noise, m) in zip(axes.ravel(), panels):
        P = np.asarray(m['patterns'], dtype=float)
        ax.axis('on')
        ax.imshow(P, cmap='gray', vmin=0, vmax=1, interpolation='nearest', aspect='auto')
        for j, improved in enumerate(m.get('improved', [True] * P.shape[1])):
            if not improved:
                ax.axvspan(j - 0.5, j + 0.5, color='tab:gray', alpha=0.6, linewidth=0)
        ax.set_title(f'{name} {noise}', fontsize=9)
        ax.set_xticks(range(P.shape[1]), [str(j + 1) for j in range(P.shape[1])], fontsize=7)
        ax.set_yticks(range(P.shape[0]), [str(i) for i in range(P.shape[0])], fontsize=6)
        ax.set_xlabel('image', fontsize=8)
        ax.set_ylabel('site' if P.shape[0] <= 8 else 'LED (site*4+colour)', fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_answers(doc: dict, path) -> Path | None:
    """The calibrated answers of each method at the first noise setting: the reliability
    diagram (accuracy against confidence per bin, the diagonal is calibrated; marker area by
    answers) and accuracy against coverage (the surest answers kept first). None when no
    method has answers (`lightstage eval --no-answers`)."""
    methods = {n: m['answers'] for n, m in doc['methods'].items() if m.get('answers')}
    if not methods:
        return None
    fig, (rel, cov) = plt.subplots(1, 2, figsize=(9.6, 4.4))
    rel.plot([0, 1], [0, 1], color='gray', linewidth=0.8)
    for name, a in methods.items():
        bins = a['reliability']['full']
        line, = rel.plot([b['confidence'] for b in bins], [b['accuracy'] for b in bins],
                         linestyle=STYLE.get(name, ('-', 'o'))[0], label=(
                             f'{name} (error {a["full_calibration_error"]:.3f})'))
        rel.scatter([b['confidence'] for b in bins], [b['accuracy'] for b in bins],
                    s=[8 + 200 * b['answers'] / a['answers'] for b in bins],
                    color=line.get_color())
        curve = a['coverage_curve']
        cov.plot([100 * c['coverage'] for c in curve], [100 * c['accuracy'] for c in curve],
                 linestyle=STYLE.get(name, ('-', 'o'))[0], marker=STYLE.get(name, ('-', 'o'))[1],
                 color=line.get_color(), label=name)
    rel.set_xlabel('calibrated probability of the answer (every exposure)')
    rel.set_ylabel('share of answers right')
    rel.set_xlim(0, 1)
    rel.set_ylim(0, 1)
    rel.set_title('reliability on held-out samples', fontsize=9)
    cov.set_xlabel('answers kept, surest first (%)')
    cov.set_ylabel('accuracy of the kept answers %')
    cov.set_title('accuracy against coverage (the rest: not sure)', fontsize=9)
    for ax in (rel, cov):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
