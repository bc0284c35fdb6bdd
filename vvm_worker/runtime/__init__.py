"""The V8 runtime of virtual vehicles: the VVM-API, deterministic replay, quotas.

Pure Python over mini-racer; no Django import (tests check this).
"""

from vvm_worker.runtime.answers import (
    answer_call,
    answer_call_error,
    answer_message,
    answer_part,
    answer_reject,
    answer_task,
)
from vvm_worker.runtime.context import VVContext
from vvm_worker.runtime.engine import Runtime, run_step
from vvm_worker.runtime.instrument import ReservedNameError, instrument
from vvm_worker.runtime.syntax import SyntaxProblem, check_syntax
from vvm_worker.runtime.types import (
    VVM_API_CALLS,
    Effect,
    ErrorKind,
    Limits,
    Outcome,
    PendingRequest,
    StepInput,
    StepResult,
    TaskRequest,
    VVError,
    place_text,
)

__all__ = [
    "VVM_API_CALLS",
    "Effect",
    "ErrorKind",
    "Limits",
    "Outcome",
    "PendingRequest",
    "ReservedNameError",
    "Runtime",
    "StepInput",
    "StepResult",
    "SyntaxProblem",
    "TaskRequest",
    "VVContext",
    "VVError",
    "answer_call",
    "answer_call_error",
    "answer_message",
    "answer_part",
    "answer_reject",
    "answer_task",
    "check_syntax",
    "instrument",
    "place_text",
    "run_step",
]
