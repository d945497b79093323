"""What the peers of lifecycle/benches/explore.rs share about its JSON instances (the
configuration problem, written from the environment and the candidate table): a target's
reach, and the further CUs a transformation may run."""


def reach(tfs, starts, usable=lambda p: True):
    """The transformations that may take part in feeding from `starts`: their closure through
    the inputs' providers, over the providers `usable` accepts."""
    seen, stack = set(), list(starts)
    while stack:
        t = stack.pop()
        if t in seen:
            continue
        seen.add(t)
        for ins in tfs[t]["inputs"]:
            stack.extend(p for p, _port in ins if usable(p))
    return seen


def further_kinds(tf):
    """How many further CUs of transformation `tf` cost nothing (its other protected CUs) and
    how many its upkeep only (its other existing CUs), beyond the first node; any more are
    spawns."""
    protected_cus = tf.get("protected_cus", 1 if tf["protected"] else 0)
    other_cus = tf.get("other_cus", 0)
    if protected_cus > 0:
        return protected_cus - 1, other_cus
    return 0, max(other_cus - 1, 0)


def answer(status, cost, unsatisfied, bound, bound_unsatisfied, chosen, further_cus, seconds, **more):
    """The one JSON object a peer prints (what lifecycle/benches/explore.rs reads): the
    configuration found (its cost, targets left unsatisfied, transformations chosen, further
    CUs), the proven bound when it is for as many unsatisfied targets, the status and time."""
    return {
        "status": status,
        "cost": cost,
        "unsatisfied": unsatisfied,
        "bound": bound if bound_unsatisfied == unsatisfied else None,
        "bound_unsatisfied": bound_unsatisfied,
        "chosen": chosen,
        "further_cus": further_cus,
        "seconds": seconds,
        **more,
    }
