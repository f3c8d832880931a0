"""Check lagrseq MCAP logs as a third party would: the plain ``mcap`` reader, ``json`` and
docs/logs.md's definitions, no lagrseq.

Run as ``python third_party_check.py [--store FILE.jsonl] LOG.mcap...``: it recomputes every
query (prompt -> prompt_sha256, the answer of a replayed query from the store, acceptance, cost,
outcome) and every episode (from its transitions and queries), prints a JSON summary and exits
1 with one line per failure. A field it needs that a record lacks is a failure. It refuses to
import lagrseq (an import guard), so it shows the logs are checkable without it.
"""

from __future__ import annotations

import hashlib
import importlib.abc
import json
import sys
from collections import Counter, defaultdict
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10: the backport lagrseq depends on there
    import tomli as tomllib


class _NoLagrseq(importlib.abc.MetaPathFinder):
    def find_spec(self, name: str, path: Any = None, target: Any = None) -> None:
        if name == "lagrseq" or name.startswith("lagrseq."):
            raise ImportError(f"{name}: this checker must not use lagrseq")
        return None


sys.meta_path.insert(0, _NoLagrseq())

from mcap.reader import make_reader  # noqa: E402

DECISION_NEEDS = ("trial", "episode", "step", "global_step", "state", "decision")
QUERY_NEEDS = ("queried", "prompt", "prompt_sha256", "answer", "evaluation", "accepted", "provider", "source", "outcome", "cost_usd")
"""What a query's record must hold (never at its default, so never left out)."""
QUERY_DEFAULTS = {"queried": False, "query_reward": 0.0}
"""docs/logs.md: a /query record leaves out every field after decision at its default: null,
but these."""
EPISODE_NEEDS = (
    "trial", "episode", "return", "length", "queries", "accepted", "guided_steps", "global_step", "cut_by_step_budget",
)
TRANSITION_NEEDS = ("step", "global_step", "reward", "terminated", "truncated", "guided")
OUTCOME = {"live": "sent", "recorded": "replayed", "miss": "refused_miss", "calibrated": "calibrated_draw"}
NO_TOKENS = ("refused_miss", "calibrated_draw")


class Check:
    def __init__(self) -> None:
        self.failures: list[str] = []

    def that(self, ok: bool, what: str) -> bool:
        if not ok:
            self.failures.append(what)
        return ok

    def fields(self, record: dict[str, Any], names: tuple[str, ...], where: str) -> bool:
        missing = [name for name in names if name not in record]
        return self.that(not missing, f"{where}: missing field(s) {', '.join(missing)}")


def read(path: str) -> tuple[dict[str, dict[str, str]], dict[str, list[dict[str, Any]]]]:
    with open(path, "rb") as handle:
        reader = make_reader(handle)
        metadata = {record.name: dict(record.metadata) for record in reader.iter_metadata()}
        topics: dict[str, list[dict[str, Any]]] = defaultdict(list)
        for _schema, channel, message in reader.iter_messages(log_time_order=True):
            topics[channel.topic].append(json.loads(message.data))
    return metadata, topics


def expand(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Columnar records (``/transitions``, ``/no_query``): entry i of every array is one record."""
    out = []
    for record in records:
        columns = {name: value for name, value in record.items() if isinstance(value, list)}
        for row in zip(*columns.values()):
            out.append({"trial": record["trial"], "episode": record["episode"], **dict(zip(columns, row))})
    return out


def load_store(path: str | None) -> dict[tuple[str, int], dict[str, Any]]:
    if path is None:
        return {}
    with open(path, encoding="utf-8") as handle:
        lines = [json.loads(line) for line in handle if line.strip()]
    return {(line["key"], line["index"]): line for line in lines}


def record_key(request: dict[str, Any]) -> str:
    text = json.dumps(request, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def price_of(prices: dict[str, dict[str, Any]], *models: str | None) -> dict[str, Any] | None:
    """docs/logs.md: a model's prices, looked up exactly, then by its longest listed prefix + '-'."""
    for model in models:
        if not model:
            continue
        if model in prices:
            return prices[model]
        family = [name for name in prices if model.startswith(name + "-")]
        if family:
            return prices[max(family, key=len)]
    return None


def cost(q: dict[str, Any], price: dict[str, Any]) -> float:
    cached = q["cached_tokens"] or 0
    cached_rate = price.get("cached_input_usd_per_mtok", price["input_usd_per_mtok"])
    return (
        (q["prompt_tokens"] - cached) * price["input_usd_per_mtok"]
        + cached * cached_rate
        + q["completion_tokens"] * price["output_usd_per_mtok"]
    ) / 1_000_000


def check_query(q: dict[str, Any], run: dict[str, Any], store: dict[tuple[str, int], dict[str, Any]], check: Check) -> str | None:
    where = f"/query trial {q.get('trial')} step {q.get('global_step')}"
    if not check.fields(q, DECISION_NEEDS, where) or q["decision"] != 1:
        return None
    if not check.fields(q, QUERY_NEEDS, where):
        return None
    q = {"parse_error": None, "record_key": None, "sample_index": None, "prompt_tokens": None, "completion_tokens": None,
         "cached_tokens": None, **q}
    threshold = float(run["config"]["lagr"]["threshold"])
    check.that(hashlib.sha256(q["prompt"].encode("utf-8")).hexdigest() == q["prompt_sha256"], f"{where}: prompt_sha256")
    parsed = q["parse_error"] is None
    check.that(q["accepted"] == (parsed and q["evaluation"] >= threshold), f"{where}: accepted")
    source, outcome = q["source"], q["outcome"]
    wanted = ("mock_fallback" if q["provider"].startswith("recorded") else "mock") if source == "mock" else OUTCOME.get(source)
    check.that(outcome == wanted, f"{where}: outcome {outcome} for source {source}")
    if outcome != "sent":
        check.that(q["cost_usd"] == 0, f"{where}: a {outcome} query cost {q['cost_usd']}")
    else:
        price = price_of(run["prices"], q["model"], run["config"]["llm"]["model"])
        if check.that(price is not None, f"{where}: no price for {q['model']} in the price table given"):
            assert price is not None
            check.that(abs(q["cost_usd"] - cost(q, price)) <= 1e-12, f"{where}: cost_usd {q['cost_usd']} != {cost(q, price)}")
    if outcome in NO_TOKENS:
        check.that(q["prompt_tokens"] is None and q["completion_tokens"] is None, f"{where}: tokens of a {outcome}")
    if outcome == "refused_miss":
        check.that(q["answer"] == "" and q["accepted"] is False, f"{where}: a refused miss answered")
    if outcome == "replayed":
        line = store.get((q["record_key"], q["sample_index"]))
        if check.that(line is not None, f"{where}: the store has no sample {q['record_key']}#{q['sample_index']}"):
            assert line is not None
            check.that(record_key(line["request"]) == q["record_key"], f"{where}: record_key is not the request's hash")
            check.that(line["request"]["messages"][-1]["content"] == q["prompt"], f"{where}: the store's prompt differs")
            check.that(line["sample"]["text"] == q["answer"], f"{where}: the answer differs from the store's")
            usage = line["sample"].get("usage")
            tokens = None if usage is None else usage["prompt_tokens"]
            check.that(q["prompt_tokens"] == tokens, f"{where}: prompt_tokens {q['prompt_tokens']} != recorded {tokens}")
    return str(outcome)


def check_episodes(
    episodes: list[dict[str, Any]], steps: list[dict[str, Any]], queries: list[dict[str, Any]], max_steps: int, check: Check
) -> None:
    by_episode: dict[tuple[int, int], list[dict[str, Any]]] = defaultdict(list)
    for step in steps:
        check.fields(step, TRANSITION_NEEDS, f"/transition trial {step.get('trial')}")
        by_episode[(step["trial"], step["episode"])].append(step)
    asked: dict[tuple[int, int], list[dict[str, Any]]] = defaultdict(list)
    for q in queries:
        if q.get("queried"):
            asked[(q["trial"], q["episode"])].append(q)
    total: dict[int, int] = defaultdict(int)
    for e in episodes:
        where = f"/episode trial {e.get('trial')} episode {e.get('episode')}"
        if not check.fields(e, EPISODE_NEEDS, where):
            continue
        own = sorted(by_episode[(e["trial"], e["episode"])], key=lambda s: s["step"])
        mine = asked[(e["trial"], e["episode"])]
        total[e["trial"]] += len(own)
        check.that(e["length"] == len(own), f"{where}: length")
        check.that(abs(e["return"] - sum(s["reward"] for s in own)) < 1e-9, f"{where}: return")
        check.that(e["guided_steps"] == sum(bool(s["guided"]) for s in own), f"{where}: guided_steps")
        check.that(e["queries"] == len(mine), f"{where}: queries")
        check.that(e["accepted"] == sum(q["accepted"] is True for q in mine), f"{where}: accepted")
        check.that(e["global_step"] == total[e["trial"]], f"{where}: global_step")
        last = own[-1]
        cut = bool(max_steps) and last["global_step"] + 1 >= max_steps and not (last["terminated"] or last["truncated"])
        check.that(e["cut_by_step_budget"] == cut, f"{where}: cut_by_step_budget {e['cut_by_step_budget']}, expected {cut}")


def check_log(path: str, store: dict[tuple[str, int], dict[str, Any]], check: Check) -> dict[str, Any]:
    metadata, topics = read(path)
    run = metadata.get("lagrseq.run", {})
    check.that(run.get("log_format") == "4", f"{path}: log_format {run.get('log_format')}")
    config = json.loads(run["config"])
    max_steps = int(config["run"]["max_steps"] or 0)
    table = json.loads(run["provider_options"]).get("price_table")
    prices: dict[str, dict[str, Any]] = {}
    if table:  # the price table in force (lagrseq's built-in one is not read here)
        with open(table, "rb") as handle:
            prices = tomllib.load(handle).get("models", {})
    queries = topics["/query"]
    decisions = queries + [{**d, "decision": 0, "queried": False} for d in expand(topics["/no_query"])]
    known = {"config": config, "prices": prices}
    outcomes = Counter(o for q in queries if (o := check_query(q, known, store, check)) is not None)
    steps = expand(topics["/transitions"])
    check_episodes(topics["/episode"], steps, decisions, max_steps, check)
    records = metadata.get("lagrseq.records", {})
    counted = {"/transition": len(steps), "/query": len(decisions), "/episode": len(topics["/episode"])}
    for topic, count in counted.items():
        check.that(records.get(topic) == str(count), f"{path}: lagrseq.records {topic} {records.get(topic)} != {count}")
    return {
        "queries": sum(outcomes.values()),
        "outcomes": dict(outcomes),
        "cost_usd": sum(q["cost_usd"] for q in queries if q.get("queried")),
        "episodes": len(topics["/episode"]),
        "cut_by_step_budget": sum(bool(e.get("cut_by_step_budget")) for e in topics["/episode"]),
        "steps": len(steps),
    }


def main(argv: list[str]) -> int:
    store_path = None
    if argv[:1] == ["--store"]:
        store_path, argv = argv[1], argv[2:]
    store = load_store(store_path)
    check = Check()
    summary = {path: check_log(path, store, check) for path in argv}
    print(json.dumps({"logs": summary, "lagrseq_imported": "lagrseq" in sys.modules}))
    for failure in check.failures:
        print(failure, file=sys.stderr)
    return 1 if check.failures else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
