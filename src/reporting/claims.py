"""Li et al.'s ablation claims (section 4.3, Tables 5-6, Figure 4; references.json) beside ours:
pairs of experiments, "changed minus base", and the expected sign of that difference at the
claim's horizons. Ours (mean over each side's seeds) are marked where within li2018_h36m's seed
spread, which one seed per ablation cannot tell apart. li2018_h36m_C20 is li2018_h36m's config
under another run_name: then the C = 20 points are li2018_h36m's, its run checked against them.
"""

from __future__ import annotations

from types import SimpleNamespace

from src.reporting.frame import HORIZONS, SELECTIONS, Results, ms_list, signed
from src.reporting.groups import settings
from src.reporting.published import REFERENCES, published_frame
from src.reporting.tables import AVERAGE, fmt, markdown

FULL, C20 = "li2018_h36m", "li2018_h36m_C20"
SHORT_PROTOCOLS = {"srnn": "8 windows", "random": "256 windows"}


def claims() -> list[SimpleNamespace]:
    """The claims, each pair with the paper's {ms: changed - base} or None, numbers filled in."""
    f = published_frame()
    f = f[(f.paper == "li2018") & f.table.isin([5, 6]) & (f.action == AVERAGE)]
    printed = {k: r.set_index("ms").value.sort_index() for k, r in f.groupby(["table", "method"])}
    words = {f"t{t}_{m}": " ".join(f"{v:.2f}" for v in r) for (t, m), r in printed.items()}
    paper = lambda t, a, b: (printed[t, a] - printed[t, b]).dropna().to_dict()  # noqa: E731
    out = []
    for claim in REFERENCES["claims"]:
        pairs = [(a, b, ref and paper(*ref)) for a, b, ref in claim["pairs"]]
        diff = pairs[0][2] or {0: 0}
        low, high = signed(min(diff.values())), signed(max(diff.values()))
        text = claim["text"].format(**words, ms="80, 160, 320, 400 and 1000 ms", low=low, high=high)
        out.append(SimpleNamespace(**{**claim, "text": text, "pairs": pairs}))
    return out


def _differences(a, b) -> list[str]:
    """What two groups differ in (budget, groups.SECTIONS): `key a vs b`, sections in one only."""
    ia, ib = (settings(g.runs[0]["config"]) | {"iterations": str(g.iterations)} for g in (a, b))
    out = [f"{k} {ia[k]} vs {ib[k]}" for k in sorted(ia.keys() & ib.keys()) if ia[k] != ib[k]]
    for mine, theirs, who in ((ia, ib, a), (ib, ia, b)):
        sections = sorted({k.split(".")[0] for k in mine.keys() - theirs.keys()})
        out += [f"{s}.* settings only in {who.label}" for s in sections]
    return out


def _nearest(groups: list, run_name: str, near):
    """The group of `run_name` on H3.6M of `near`'s budget, its settings nearest `near`'s."""
    found = [g for g in groups if g.run_name == run_name and g.dataset == "h36m"]
    if not found or near is None:
        return max(found, key=lambda g: len(g.runs), default=None)
    return min(found, key=lambda g: (g.iterations != near.iterations, len(_differences(g, near))))


def _verdict(claim, delta: dict[int, float], spread: dict[int, float] | None) -> str:
    if not (horizons := [ms for ms in claim.horizons if ms in delta]):
        return "no common horizon"
    clear = [ms for ms in horizons if spread is not None and abs(delta[ms]) > spread.get(ms, 0)]
    if claim.expect == "no gain":
        if gains := [ms for ms in clear if delta[ms] > 0]:
            return f"disagrees: the base is clearly better at {ms_list(gains)}"
        if spread is None:
            return "no seed spread to judge by"
        return "agrees: no gain beyond the seed spread"
    opposite = [ms for ms in horizons if delta[ms] <= 0]
    if spread is None:  # +0.00 has no direction a reader can see: named, not counted
        zero = [ms for ms in horizons if round(delta[ms], 2) == 0]
        same = sum(1 for ms in horizons if delta[ms] > 0 and ms not in zero)
        zero = f", 0.00 at {ms_list(zero)}" if zero else ""
        return f"same direction at {same} of {len(horizons)}{zero} (no seed spread to judge by)"
    if against := [ms for ms in opposite if ms in clear]:
        return f"disagrees: opposite beyond the spread at {ms_list(against)}"
    if not opposite and len(clear) == len(horizons):
        return "agrees, beyond the seed spread"
    unclear = ms_list([ms for ms in horizons if ms not in clear])
    if not opposite:
        return f"same direction; cannot tell at {unclear} (within the spread)"
    return f"cannot tell: within the seed spread at {unclear}"


def _seeds(group) -> str:
    return f"{len(group.runs)} seed{'s' if len(group.runs) != 1 else ''}"


def _c20_line(full, c20) -> str:
    if c20 is not None and (differ := _differences(c20, full)):
        return f"{c20.label} differs from {full.label} in {'; '.join(differ)}: C = 20 on its own."
    return (
        f"C = 20 with the regulariser is {full.label}'s configuration: its points are "
        f"{full.label}'s, the mean over its {_seeds(full)}."
    )


def _pair(results: Results, claim, pair, full, protocols, spread) -> tuple[list, str | None]:
    """The rows of a pair (the paper's, ours or "not trained") and what the two differ in."""
    changed_name, base_name, paper = pair
    name = lambda n: n if n == FULL else n.removeprefix("li2018_h36m_")  # noqa: E731
    label = f"{name(changed_name)} − {name(base_name)}"
    changed = _nearest(results.groups, changed_name, full)
    base = _nearest(results.groups, base_name, changed or full)
    if base_name == C20 and (base is None or not _differences(base, full)):
        base = full  # li2018_h36m's configuration: its seeds are C = 20's
    rows = []
    if paper is not None:
        cells = [signed(paper[ms]) if ms in paper else "-" for ms in HORIZONS]
        rows.append([f"{label}, paper", "-", "-", *cells, ""])
    if changed is None or base is None:
        missing = [n for n, g in ((changed_name, changed), (base_name, base)) if g is None]
        rows.append([label, "-", "-", *["-"] * len(HORIZONS), f"not trained: {', '.join(missing)}"])
        return rows, None
    first = f"{label} ({_seeds(changed)} and {_seeds(base)})"
    for p in protocols:
        for s in SELECTIONS:
            a, b, gap = results.means(changed, p, s), results.means(base, p, s), spread[p, s]
            delta = {ms: a[ms] - b[ms] for ms in HORIZONS if ms in a and ms in b}
            # A difference within the seed spread is printed in parentheses.
            within = {ms for ms in delta if gap is not None and abs(delta[ms]) <= gap.get(ms, 0)}
            cells = [signed(delta[ms]) if ms in delta else "-" for ms in HORIZONS]
            cells = [f"({c})" if ms in within else c for c, ms in zip(cells, HORIZONS, strict=True)]
            rows.append([first, SHORT_PROTOCOLS.get(p, p), s, *cells, _verdict(claim, delta, gap)])
            first = ""
    differ = _differences(changed, base)
    listing = "; ".join(differ[:4]) + ("; …" if len(differ) > 4 else "") or "nothing but run_name"
    return (
        rows,
        f"- {label}: {changed.label} against {base.label}; their configs differ in {listing}.",
    )


def claims_section(results: Results, protocols: list[str], heading: str) -> list[str]:
    """The section, [] unless li2018_h36m and an ablation were trained; a claim once a pair is."""
    ablations = [g for g in results.groups if g.ablation and g.dataset == "h36m"]
    full = _nearest(results.groups, FULL, ablations[0] if ablations else None)
    if full is None or not ablations:
        return []
    spread = {(p, s): results.spread(full, p, s) for p in protocols for s in SELECTIONS}
    columns = ["difference", "protocol", "checkpoint", *[f"{ms} ms" for ms in HORIZONS]]
    shown = []
    for claim in claims():
        pairs = [_pair(results, claim, pair, full, protocols, spread) for pair in claim.pairs]
        if notes := [note for _, note in pairs if note]:  # a pair was trained
            table = [r for rows, _ in pairs for r in rows]
            table = markdown(table, [*columns, "against the claim"])
            shown += [f"### {claim.title}", "", claim.text, "", table, "", *notes, ""]
    if not shown:
        return []
    rows = [
        [f"seed spread of {full.label}", SHORT_PROTOCOLS.get(p, p), s]
        + [fmt((spread[p, s] or {}).get(ms)) for ms in HORIZONS]
        for p in protocols
        for s in SELECTIONS
    ]
    intro = (
        "Li et al.'s ablation claims (section 4.3, Tables 5 and 6, Figure 4) beside ours: the "
        "average Euler error of the changed experiment minus the base's, each the mean over its "
        "seeds (positive: the change raised the error). In parentheses: not larger than the seed "
        f"spread of {full.label} ({_seeds(full)}, largest minus smallest seed average below), so "
        "these runs cannot tell its sign."
    )
    c20 = _c20_line(full, _nearest(results.groups, C20, full))
    return [f"## {heading}", "", intro, "", markdown(rows, columns), "", c20, "", *shown]
