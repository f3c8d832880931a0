"""Cube stacking (SPEC section 1): cubes, targets, E = l_s * C(s), the prompt, the answer parser,
pi_LLM and a rule-based extrapolator that reads only the prompt.

A pattern is a tuple of cube ids from bottom to top; id 0 is cube 'a' (the paper numbers cubes
from 1, so paper cube k is id k - 1).

Stack sizes:
- 8 cubes: the released code's cubes and target e,f,g,a,b,c,d,h (decreasing edge length; the paper
  also names e,f,g,a,b,c,h,d, which the code does not accept, and neither does lagrseq).
- 11 cubes: the target f,k,e,j,d,i,c,h,b,g,a of the authors' 11-cube cache (SPEC section 5). Its
  descriptor is not published; we give red cubes a..f the odd edge lengths 1..11 cm and blue cubes
  g..k the even lengths 2..10 cm, so the target is again "decreasing edge length" (and alternates
  colours).
- 5 cubes: our own member of the same family: red a (5 cm), b (3 cm); blue c (6 cm), d (4 cm),
  e (2 cm); target c,a,d,b,e, decreasing edge length.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from lagrseq.tasks.base import Parsed, clip_token, unreadable_answer

LETTERS = "abcdefghijklmnopqrstuvwxyz"


@dataclass(frozen=True)
class Cube:
    """One cube of the table."""

    letter: str
    colour: str
    edge_cm: int


def _cubes(spec: str) -> tuple[Cube, ...]:
    out = []
    for item in spec.split():
        letter, colour, edge = item.split(":")
        out.append(Cube(letter, colour, int(edge)))
    return tuple(out)


# The stack sizes lagrseq knows: cubes and the target order (ids).
CUBE_SETS: dict[int, tuple[tuple[Cube, ...], tuple[int, ...]]] = {
    5: (_cubes("a:Red:5 b:Red:3 c:Blue:6 d:Blue:4 e:Blue:2"), (2, 0, 3, 1, 4)),
    8: (
        _cubes("a:Red:5 b:Red:4 c:Red:3 d:Red:2 e:Blue:10 f:Blue:8 g:Blue:6 h:Blue:2"),
        (4, 5, 6, 0, 1, 2, 3, 7),
    ),
    11: (
        _cubes(
            "a:Red:1 b:Red:3 c:Red:5 d:Red:7 e:Red:9 f:Red:11 "
            "g:Blue:2 h:Blue:4 i:Blue:6 j:Blue:8 k:Blue:10"
        ),
        (5, 10, 4, 9, 3, 8, 2, 7, 1, 6, 0),
    ),
}


def format_stack(ids: tuple[int, ...] | list[int]) -> str:
    """A stack as the released code writes it into prompts: ``['e','f','g']`` (no spaces)."""
    return "[" + ",".join(f"'{LETTERS[i]}'" for i in ids) + "]"


def _descriptor_objects(cubes: tuple[Cube, ...]) -> str:
    lines = "".join(
        f"     - {c.colour} cube of edge length {c.edge_cm}cm (represented by '{c.letter}')\n"
        for c in cubes
    )
    return "\n    A table contains the following objects: \n" + lines + "\n\n"


@dataclass(frozen=True)
class CubeStacking:
    """The cube-stacking task for one stack size."""

    stack_size: int = 8
    name: str = "cube-stacking"
    relabel: tuple[int, ...] | None = None
    """A relabelled cube set (``lagrseq screen --prompt-set relabelled``): the table's cube i is
    called ``LETTERS[relabel[i]]``; the same cubes (colour, edge length) and the same rule
    (decreasing edge length), so the target is the same stack under other letters and the
    prompt lists the cubes in the order of their new letters. None: the released letters."""

    def __post_init__(self) -> None:
        if self.stack_size not in CUBE_SETS:
            raise ValueError(
                f"stack_size {self.stack_size} unknown; expected one of {sorted(CUBE_SETS)}"
            )
        if self.relabel is not None and sorted(self.relabel) != list(range(self.stack_size)):
            raise ValueError(f"relabel {self.relabel} is not a permutation of the {self.stack_size} cubes")

    @property
    def cubes(self) -> tuple[Cube, ...]:
        cubes = CUBE_SETS[self.stack_size][0]
        if self.relabel is None:
            return cubes
        by_letter = sorted(range(self.stack_size), key=lambda i: self.relabel[i])  # type: ignore[index]
        return tuple(Cube(LETTERS[j], cubes[i].colour, cubes[i].edge_cm) for j, i in enumerate(by_letter))

    @property
    def target(self) -> tuple[int, ...]:
        target = CUBE_SETS[self.stack_size][1]
        return target if self.relabel is None else tuple(self.relabel[i] for i in target)

    @property
    def n_actions(self) -> int:
        """Action 0 removes the top cube; action k adds cube k - 1."""
        return self.stack_size + 1

    # ---------------------------------------------------------------- evaluation (SPEC 1.1)
    def correct_positions(self, pattern: tuple[int, ...]) -> int:
        """C(s): positions whose cube equals the target's cube there."""
        return sum(1 for a, b in zip(pattern, self.target) if a == b)

    def evaluation(self, pattern: tuple[int, ...]) -> int:
        """E(s) = l_s * C(s), the paper's evaluation of a stack."""
        return len(pattern) * self.correct_positions(pattern)

    def is_complete(self, pattern: tuple[int, ...]) -> bool:
        return tuple(pattern) == self.target

    def evaluate(self, solution: tuple[int, ...]) -> float:
        """E(s_LLM) / E(target) in [0, 1] (parsed solutions are never longer than the stack)."""
        return self.evaluation(tuple(solution)) / float(self.stack_size**2)

    def coerce_pattern(self, value: object) -> tuple[int, ...]:
        """A partial stack from outside data (an authors' cache key, an MCAP ``state``): a
        sequence of distinct cube ids of this table, at most ``stack_size`` long. Raises
        ``ValueError`` saying what is wrong otherwise."""
        if isinstance(value, np.ndarray):
            if value.ndim != 1:
                raise ValueError(f"expected a 1-D list of cube ids, found an array of shape {value.shape}")
            value = value.tolist()
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"expected a list of cube ids, found {type(value).__name__}")
        if len(value) > self.stack_size:
            raise ValueError(f"expected at most {self.stack_size} cube ids, found {len(value)}")
        ids = []
        for item in value:
            if isinstance(item, bool) or not isinstance(item, (int, np.integer)):
                shown = repr(item) if isinstance(item, (int, float, str, bytes, type(None))) else type(item).__name__
                raise ValueError(f"expected cube ids (integers), found {shown if len(shown) <= 40 else shown[:37] + '...'}")
            if not 0 <= int(item) < self.stack_size:
                raise ValueError(f"cube id {item} is not one of the {self.stack_size} cubes (0..{self.stack_size - 1})")
            ids.append(int(item))
        if len(set(ids)) != len(ids):
            raise ValueError(f"a cube appears twice in {ids}")
        return tuple(ids)

    def prefixes(self) -> list[tuple[int, ...]]:
        """Every non-empty prefix of the target: the states a cube query can come from when wrong
        cubes are taken off again (what ``lagrseq record`` asks by default)."""
        return [self.target[:n] for n in range(1, self.stack_size + 1)]

    def is_partial(self, solution: tuple[int, ...]) -> bool:
        """A parsed answer that lists fewer or more cubes than the stack holds (``lagrseq record
        --census`` counts it apart from a wrong one)."""
        return len(solution) != self.stack_size

    def shown(self, prompt: str) -> int:
        """How many cubes the partial stack of ``prompt`` shows (the census's ``shown``);
        ValueError for a prompt that is not a cube prompt."""
        return len(partial_stack(prompt))

    def progress(self, pattern: tuple[int, ...]) -> int:
        """Stack height (in the released code the stack is always a correct prefix)."""
        return len(pattern)

    def render(self, pattern: tuple[int, ...]) -> str:
        return "".join(LETTERS[i] for i in pattern) or "(empty)"

    # ---------------------------------------------------------------- prompt (SPEC section 6)
    @cached_property
    def _objects_text(self) -> str:
        return _descriptor_objects(self.cubes)

    def prompt(self, pattern: tuple[int, ...]) -> str:
        """The released code's prompt, byte for byte for 8 cubes: instructions and example first,
        then a triple-backtick block with the objects and the partial stack."""
        text = (
            self._objects_text
            + "    A human is currently stacking some of the cubes in the following sequence"
            " (from bottom to top): \n    " + format_stack(pattern)
        )
        return (
            "You are an organizing robot. Stack the remaining cubes in the pattern that human"
            " seems to be following.     The final stack should have all"
            f" {self.stack_size} cubes. Lets think step by step.    For example, if the stack is"
            " initially in the order (bottom to top)    ['a','d','b']\n"
            "    Then, the explanation is that the human is likely first stacking the red cubes"
            " irrespective of their edge lengths,     followed by the blue cubes. So a possible"
            " order would be: (bottom to top):    ['a','d','b','c','f','e','g','h']\n"
            "    Make sure your response contains only the order in the form of a list and not"
            " the explanation.\n"
            f"    ```{text}```\n    "
        )

    # ---------------------------------------------------------------- answer parser
    def parse(self, text: str) -> Parsed:
        """Read a cube order from an answer.

        Accepts a list in brackets (quotes, spaces and prose around it are fine; the last
        bracketed list that reads as cubes wins), a comma- or space-separated run of letters, or
        one word of letters such as ``efgabcdh``. Refuses, with the reason: no list found, a token
        that is not a cube of this table, a cube named twice, more cubes than the table has.
        Unlike the released parser, an unknown character never repeats the previous letter.
        An answer longer than ``MAX_ANSWER_CHARS`` is refused unread. Time linear in the
        answer's length.
        """
        problem = unreadable_answer(text)
        if problem is not None:
            return Parsed(None, problem)
        known = {c.letter: i for i, c in enumerate(self.cubes)}
        candidates = _LIST.findall(text)
        errors: list[str] = []
        for body in reversed(candidates):
            tokens = [t.strip().strip("'\"`").strip() for t in body.split(",")]
            tokens = [t for t in tokens if t]
            if len(tokens) == 1 and len(tokens[0]) > 1 and tokens[0].isalpha():
                tokens = list(tokens[0])  # ['efgabcdh']
            result = self._ids(tokens, known)
            if result.ok:
                return result
            errors.append(result.error or "")
        if not candidates:
            stripped = text.strip().strip("`").strip()
            words = _WORD.findall(stripped)
            if len(words) == 1 and len(words[0]) > 1:
                return self._ids(list(words[0]), known)
            if words and all(len(w) == 1 for w in words):
                return self._ids(words, known)
            return Parsed(None, f"no list of cubes found in {_clip(text)}")
        return Parsed(None, errors[0])

    def _ids(self, tokens: list[str], known: dict[str, int]) -> Parsed:
        if not tokens:
            return Parsed(None, "empty list")
        ids: list[int] = []
        for token in tokens:
            letter = token.lower()
            if letter not in known:
                return Parsed(None, f"{clip_token(token)} is not a cube of this table")
            if known[letter] in ids:
                return Parsed(None, f"cube {letter!r} appears twice")
            ids.append(known[letter])
        if len(ids) > self.stack_size:
            return Parsed(None, f"{len(ids)} cubes listed, the table has {self.stack_size}")
        return Parsed(tuple(ids))

    # ---------------------------------------------------------------- pi_LLM
    def guided_cell(
        self, pattern: tuple[int, ...], solution: tuple[int, ...], cursor: object = None
    ) -> None:
        """Cube stacking has no cells to choose: pi_LLM acts on the stack."""
        return None

    def guidance(
        self, pattern: tuple[int, ...], solution: tuple[int, ...], cursor: object = None
    ) -> int | None:
        """The action pi_LLM takes in ``pattern`` given an accepted solution.

        On a prefix of the solution: add its next cube. On the whole solution: re-add the top
        cube, a no-op (the released code does the same with a no-op add). Off the solution (only
        possible when P < 1 or without the wrong-cube revert): remove the top cube. If the next cube
        is already stacked (a partially wrong accepted answer), pi_LLM asks for nothing.
        """
        n = len(pattern)
        if tuple(solution[:n]) != tuple(pattern):
            return 0
        if n >= len(solution):
            return pattern[-1] + 1 if pattern else None
        nxt = solution[n]
        if nxt in pattern:
            return None
        return nxt + 1


# The answer parser's patterns; both linear-time (a bracketed body cannot hold a bracket, a word
# is one run of letters).
_LIST = re.compile(r"\[([^\[\]]*)\]")
_WORD = re.compile(r"[A-Za-z]+")


def _clip(text: str, width: int = 60) -> str:
    """``repr`` of an answer's start for a parse-error reason: at most ``width`` + 2 characters,
    also when escapes (``\x00`` for a NUL) make the repr longer than the text."""
    one = " ".join(text.split())
    shown = repr(one if len(one) <= width else one[: width - 3] + "...")
    return shown if len(shown) <= width + 2 else shown[: width - 1] + "..."


# ------------------------------------------------------------------------------------------
# Rule-based extrapolator (the mock LLM). It reads the prompt text only: the cubes of the
# descriptor and the partial stack. It never sees the target.
# ------------------------------------------------------------------------------------------
_CUBE_LINE = re.compile(r"- (\w+) cube of edge length (\d+)\s*cm \(represented by '(\w)'\)")
_PARTIAL = re.compile(r"\(from bottom to top\):\s*(\[[^\]]*\])\s*`{3}")


def _rank_orders(cubes: list[Cube], partial: list[str]) -> list[tuple[str, list[str]]]:
    """Candidate full orderings, simplest first.

    The task descriptor's own example explains a stack by colour first ("first stacking the red
    cubes irrespective of their edge lengths, followed by the blue cubes"), so colour grouping
    ranks first, then a single attribute (size), then alternation and letter order.
    """
    by_letter = {c.letter: c for c in cubes}
    colours: list[str] = []
    for letter in partial + [c.letter for c in cubes]:
        colour = by_letter[letter].colour if letter in by_letter else None
        if colour and colour not in colours:
            colours.append(colour)

    def size_key(descending: bool):
        return lambda c: (-c.edge_cm if descending else c.edge_cm, c.letter)

    def grouped(descending: bool) -> list[str]:
        out: list[str] = []
        for colour in colours:
            group = sorted((c for c in cubes if c.colour == colour), key=size_key(descending))
            out += [c.letter for c in group]
        return out

    def by_size(descending: bool) -> list[str]:
        return [c.letter for c in sorted(cubes, key=size_key(descending))]

    def alternating(descending: bool) -> list[str]:
        queues = {
            colour: sorted((c for c in cubes if c.colour == colour), key=size_key(descending))
            for colour in colours
        }
        out: list[str] = []
        while any(queues.values()):
            for colour in colours:
                if queues[colour]:
                    out.append(queues[colour].pop(0).letter)
        return out

    letters = [c.letter for c in cubes]
    return [
        ("colour groups, largest first", grouped(True)),
        ("colour groups, smallest first", grouped(False)),
        ("largest first", by_size(True)),
        ("smallest first", by_size(False)),
        ("alternating colours, largest first", alternating(True)),
        ("alternating colours, smallest first", alternating(False)),
        ("alphabetical", sorted(letters)),
        ("reverse alphabetical", sorted(letters, reverse=True)),
    ]


def consistent_orders(prompt: str) -> list[tuple[str, list[str]]]:
    """The ranked hypotheses that continue the prompt's partial stack (duplicates removed).

    If none continues it, the answer keeps the partial stack and adds the remaining cubes largest
    first (a guess, usually wrong, as a real model's would be). Worked out once per prompt (a
    cube trial asks from the same few dozen stacks over and over); each call gets its own lists.
    """
    return [(name, list(order)) for name, order in _consistent_orders(prompt)]


@lru_cache(maxsize=1024)
def _consistent_orders(prompt: str) -> tuple[tuple[str, tuple[str, ...]], ...]:
    cubes = [Cube(letter, colour, int(edge)) for colour, edge, letter in _CUBE_LINE.findall(prompt)]
    match = _PARTIAL.search(prompt)
    if not cubes or match is None:
        raise ValueError("prompt does not look like a cube-stacking prompt")
    partial = re.findall(r"'(\w)'", match.group(1))
    seen: set[tuple[str, ...]] = set()
    out = []
    for name, order in _rank_orders(cubes, partial):
        if order[: len(partial)] == partial and tuple(order) not in seen:
            seen.add(tuple(order))
            out.append((name, order))
    if not out:
        rest = [c for c in cubes if c.letter not in partial]
        rest.sort(key=lambda c: (-c.edge_cm, c.letter))
        out.append(("keep the stack, then largest first", partial + [c.letter for c in rest]))
    return tuple((name, tuple(order)) for name, order in out)


def extrapolate(prompt: str, temperature: float, rng: np.random.Generator) -> str:
    """Answer a cube-stacking prompt like a model that is told to reply with a list only.

    Temperature 0: the simplest consistent ordering. Temperature > 0: one consistent ordering drawn
    with weight exp(-rank / temperature) from ``rng``.
    """
    orders = consistent_orders(prompt)
    if temperature <= 0 or len(orders) == 1:
        choice = 0
    else:
        weights = np.exp(-np.arange(len(orders)) / float(temperature))
        choice = int(rng.choice(len(orders), p=weights / weights.sum()))
    return "[" + ", ".join(f"'{letter}'" for letter in orders[choice][1]) + "]"


# ------------------------------------------------------------------------------------------
# Calibrated mock profiles (``--provider mock:PROFILE``). A profile simulates a model whose chance of
# answering with the right completion depends on how much of the stack it was shown, measured on
# real answers; the wrong answers it gives are the extrapolator's best hypothesis that is not the
# target (for a 1-cube prefix that is GPT's actual answer, colour groups e,f,g,h,a,b,c,d). Unlike
# the rule-based extrapolator, a profile knows the target: it stands for a model of known accuracy.
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TemperatureModel:
    """ASSUMPTION (no answers above tau = 0 were published): P(correct | shown, tau) =
    P(correct | shown, 0) x (1 - tau^power x drop), where ``drop`` is ``short_drop`` while at most
    ``short_fraction`` of the stack is shown and ``long_drop`` after, tau capped at 1. It encodes
    the paper's Fig. 4 text (at tau = 1 short prefixes fail, longer ones are right but not
    uniformly) and Table 2's direction (queries rise with tau, with and without SEQ)."""

    short_fraction: float
    short_drop: float
    long_drop: float
    power: float = 1.0

    def factor(self, fraction: float, temperature: float) -> float:
        drop = self.short_drop if fraction <= self.short_fraction else self.long_drop
        return max(0.0, 1.0 - min(temperature, 1.0) ** self.power * drop)


@dataclass(frozen=True)
class AccuracyProfile:
    """P(right completion) by prefix length, per stack size it was measured on."""

    name: str
    description: str
    calibration: str
    """Where the numbers come from and how they were obtained."""
    accuracy: tuple[tuple[int, tuple[float, ...]], ...]
    """(stack size, P(correct) for prefix lengths 1..stack size) pairs."""
    temperature: TemperatureModel | None = None
    """How accuracy falls at temperature > 0 (an assumption: no answers above 0 were published)."""

    def probability(self, shown: int, stack_size: int, temperature: float = 0.0) -> float:
        """P(correct) after seeing ``shown`` of ``stack_size`` cubes at ``temperature``. Stack sizes
        without data use the table measured on the nearest size, at the nearest fraction of the
        stack shown; temperatures above 0 scale it by the profile's :class:`TemperatureModel`."""
        p = self._probability_t0(shown, stack_size)
        if self.temperature is not None and temperature > 0:
            p *= self.temperature.factor(shown / stack_size, temperature)
        return p

    def _probability_t0(self, shown: int, stack_size: int) -> float:
        tables = dict(self.accuracy)
        if stack_size in tables:
            table = tables[stack_size]
            return table[min(max(shown, 1), len(table)) - 1]
        size = min(tables, key=lambda n: (abs(n - stack_size), n))
        table = tables[size]
        index = int(np.floor(shown / stack_size * size + 0.5))
        return table[min(max(index, 1), size) - 1]


def calibrate_accuracy(pairs: list[tuple[object, object]], task: CubeStacking) -> tuple[float, ...]:
    """Fraction of answers equal to the target, per prefix length 1..N, over the pairs whose key
    is that prefix of ``task``'s target (an authors' cache read as (key, answer) pairs; answers
    that are lists, like the caches' seed pair, are read as their text)."""
    right = np.zeros(task.stack_size)
    total = np.zeros(task.stack_size)
    for key, answer in pairs:
        if not isinstance(key, (list, tuple)) or not key or tuple(key) != task.target[: len(key)]:
            continue
        text = answer if isinstance(answer, str) else repr(list(answer)) if isinstance(answer, (list, tuple)) else ""
        parsed = task.parse(text)
        total[len(key) - 1] += 1
        right[len(key) - 1] += bool(parsed.ok and task.is_complete(tuple(parsed.solution or ())))
    if not total.all():
        missing = [i + 1 for i in range(task.stack_size) if not total[i]]
        raise ValueError(f"no answers for prefix lengths {missing}")
    return tuple(float(x) for x in np.round(right / total, 2))


AUTHORS_T0 = AccuracyProfile(
    name="authors-t0",
    description="GPT (3.5, per SPEC 5) at temperature 0 as in the authors' cube caches: wrong on short "
    "prefixes, right on middle ones, wrong on the full sequence (8 cubes)",
    calibration="calibrate_accuracy over cube_stacking_cache0.0.pkl (8 cubes, 81 answers) and "
    "cube_stacking_cache0.pkl (11 cubes, 111 answers); 5 cubes use the 8-cube table by fraction shown",
    accuracy=(
        (8, (0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0)),
        (11, (0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.3, 1.0, 1.0, 1.0, 1.0)),
    ),
    temperature=TemperatureModel(short_fraction=0.25, short_drop=1.0, long_drop=0.3),
)
ORACLE = AccuracyProfile(
    name="oracle",
    description="always the right completion (an upper bound)",
    calibration="none: P(correct) = 1 by definition",
    accuracy=((8, (1.0,) * 8),),
)
PROFILES: dict[str, AccuracyProfile | None] = {
    "ideal": None,  # the rule-based extrapolator itself (the same as plain ``mock``)
    "oracle": ORACLE,
    "authors-t0": AUTHORS_T0,
}
PROFILE_HELP = {
    "ideal": "the rule-based extrapolator (target-blind; the same as plain mock)",
    "oracle": ORACLE.description,
    "authors-t0": AUTHORS_T0.description,
}


def partial_stack(prompt: str) -> list[str]:
    """The letters of the partial stack a cube prompt shows."""
    match = _PARTIAL.search(prompt)
    if match is None:
        raise ValueError("prompt does not look like a cube-stacking prompt")
    return re.findall(r"'(\w)'", match.group(1))


_DESCRIBED = re.compile(r"- (\w+) cube of edge length (\d+)cm \(represented by '(\w)'\)")


def task_of_prompt(prompt: str) -> CubeStacking:
    """The cube task a prompt was written for, read from the cubes it describes: the stack size,
    and the relabelling when the letters are not the released ones (a prompt of ``lagrseq screen
    --prompt-set relabelled``). Raises ``ValueError`` when the described cubes are no known set."""
    described = _DESCRIBED.findall(prompt)
    size = len(described)
    if size not in CUBE_SETS:
        raise ValueError(f"the prompt describes {size} cubes; expected one of {sorted(CUBE_SETS)}")
    original = {(c.colour, c.edge_cm): i for i, c in enumerate(CUBE_SETS[size][0])}
    relabel = [-1] * size
    for colour, edge, letter in described:
        i = original.get((colour, int(edge)))
        j = LETTERS.find(letter)
        if i is None or not 0 <= j < size or relabel[i] != -1:
            raise ValueError(f"the prompt's cubes are not the {size}-cube set ({colour} {edge} cm as {letter!r})")
        relabel[i] = j
    plain = tuple(relabel) == tuple(range(size))
    return CubeStacking(size, relabel=None if plain else tuple(relabel))


def profile_extrapolator(task: CubeStacking, profile: str) -> Callable[[str, float, np.random.Generator], str]:
    """The mock handler of ``--provider mock:PROFILE`` for ``task`` (a key of :data:`PROFILES`)."""
    if profile not in PROFILES:
        raise ValueError(f"unknown mock profile {profile!r}; expected one of {', '.join(PROFILES)}")
    chosen = PROFILES[profile]
    if chosen is None:
        return extrapolate
    target = [LETTERS[i] for i in task.target]

    def answer(prompt: str, temperature: float, rng: np.random.Generator) -> str:
        shown = partial_stack(prompt)
        p = chosen.probability(len(shown), task.stack_size, temperature)
        right = p >= 1.0 or (p > 0.0 and rng.random() < p)
        if right:
            order = target
        else:
            wrong = [o for _, o in consistent_orders(prompt) if o != target]
            if not wrong:  # only the target continues the prompt: rewrite the order from scratch
                cubes = [Cube(c.letter, c.colour, c.edge_cm) for c in task.cubes]
                wrong = [o for _, o in _rank_orders(cubes, []) if o != target]
            order = wrong[0]
        return "[" + ", ".join(f"'{letter}'" for letter in order) + "]"

    return answer


UPSTREAM_SHARED_ROW = "upstream-shared-row"


def upstream_state_key(pattern: tuple[int, ...], target: tuple[int, ...]) -> object:
    """The released code's Q-table row, where it differs from one row per state.

    The code indexes a stack by its lexicographic rank among the permutations of its own cubes,
    minus one, with no offset per length (SPEC 1.1). Every stack that is already in sorted
    order (rank 0) lands on row -1: for 8 cubes the stacks [], [e], [e,f] and [e,f,g] share one
    row. Other reachable stacks (always correct prefixes, because wrong cubes are reverted) get
    distinct rows, and the wrong "phantom" stacks map to rows that are never updated, so this key
    reproduces the code's table exactly on the states the code can visit.
    """
    n = len(pattern)
    if list(pattern) == sorted(pattern) and sorted(pattern) == sorted(target[:n]):
        return UPSTREAM_SHARED_ROW
    return tuple(pattern)
