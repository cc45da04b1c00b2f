# The fixed split of the 13 public corrected logs (issue 16, part 1), sourced by the benchmark
# scripts. Parameters are tuned on TUNING_LOGS only; every headline number is reported on
# HELD_OUT_LOGS with the tuning-set figure beside it. Never move a log between the two sets:
# a log that has been looked at while tuning cannot become held-out again.
# The choice (docs/benchmarks.md, "How to reproduce"): the three buildings of the
# issue's failure report (intel, aces, freiburg-079) and the worst repeated corridor
# (infinite-corridor) are tuning logs; each side gets small offices and one large or outdoor
# site (held out: acapulco's hall, freiburg-campus outdoors).
TUNING_LOGS=(aces edmonton fhw freiburg-079 infinite-corridor intel orebro)
HELD_OUT_LOGS=(acapulco belgioioso csail freiburg-101 freiburg-campus seattle)
ALL_LOGS=(acapulco aces belgioioso csail edmonton fhw freiburg-079 freiburg-101 freiburg-campus infinite-corridor intel orebro seattle)
# "tuning" or "held-out" for a log name.
log_set() {
  local log
  for log in "${TUNING_LOGS[@]}"; do [[ "$log" == "$1" ]] && { echo tuning; return; }; done
  for log in "${HELD_OUT_LOGS[@]}"; do [[ "$log" == "$1" ]] && { echo held-out; return; }; done
  echo other
}
