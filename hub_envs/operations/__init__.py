"""The operations users run on published envs, one module each: reproduce, diff, compare, evaluate, attest,
from_dataset."""
