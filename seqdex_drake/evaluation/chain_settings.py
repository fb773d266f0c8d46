"""How the chain runner (``evaluation/runner.py``) sets up each task family's chain: where the approach runs,
carries and times out (``controller/chain_controller.ChainParams``)."""

import numpy as np

from seqdex_drake.tasks.carry import CARRY_HEIGHT

#: Within a stage the approach never takes over again (a stage change restarts it), as in the envs, where nothing
#: pulls the hand back: tool Grasp's script moves the hand more than the default 0.1 m from the tool's top while it
#: grasps, block Search's moves it 14-17 cm aside of the target, Orient's fingertip strokes across the block.
REENGAGE = float("inf")
#: The Building Blocks approach crosses at this height (m) of the hand centre between the baseplate and the pile:
#: the box walls' tops are at 0.765 m, and a straight line from the baseplate ran the hanging fingers into the near
#: wall (the hand stopped against it, and the next block's Search never started).
BLOCK_TRAVEL_HEIGHT = 0.9

#: Stages entered with the approach first (``ChainParams.approach_stages``): block Orient and Grasp were trained from
#: resets with the open hand 5 cm above the block, and Search leaves the hand 14-17 cm aside of it (Orient's
#: stylus approach from there used up its 75 steps in the pile), Orient the fingertip above the block's side.
APPROACH_STAGES = {"building_blocks": ("retrieve", "orient", "grasp")}
#: Stages a feasibility switch selects only while the target object is not lifted (``ChainParams.free_object_stages``):
#: tool Grasp starts from the tool on the table, and its policy cannot put down a tool it holds, so F^reorient
#: scoring a held tool below 1 keeps tool Reorient (the sequential rule), while a dropped tool goes back to it.
#: Building Blocks: every stage before Insert starts from a block at rest (in the pile or on the table); with the
#: block lifted in Grasp's jaws, only Insert can go on from there (the others, restarted, would drop it).
FREE_OBJECT_STAGES = {"tool_positioning": ("tool_grasp",),
                      "building_blocks": ("search", "retrieve", "orient", "grasp")}
#: When the switcher computes the next stages' scores between decisions (``SwitcherParams.trigger``). Building Blocks:
#: "next", the paper's timing (c^{i+1} checked every tick, a switch as soon as it exceeds 1). Tools: "decision", the
#: walk back only where a stage ends: with "next", F^reorient handed the hammer over during tool Grasp's hold before
#: the fist had settled, and the chain succeeded in 20 of 102 held-out episodes against 31 with "decision", which
#: kept every sequential success (``results/tool_positioning.md``, "The switcher in the chain").
SWITCH_TRIGGER = {"building_blocks": "next", "tool_positioning": "decision"}
#: A block counts as lifted while its centre of mass is more than ``HELD_LIFT`` (7.5 cm) over this height above the
#: table, 10.5 cm in all (``ChainRunner.start_block``): a block resting on the table has it at most 6 cm up (a 1x4
#: on an end); Grasp lifts blocks about 0.5 m.
BLOCK_REST_HEIGHT = 0.03
#: Stages entered with the approach carrying the held block to this height (m) above its goal
#: (``ChainParams.carry_stages``): Insert's script carries it 3 cm above its goal before it lowers it, and the way
#: there from Grasp's lift (about 1.1 m high, anywhere over the box) was more than its 125 steps at the wrist's
#: 0.3 m/s: from 60 Grasp hand-offs Insert succeeded in none (``seqdex pipeline``'s transitions).
CARRY_STAGES = {"building_blocks": (("insert", CARRY_HEIGHT),)}
#: The carry also turns the held object to its goal's orientation, the goal the same turned by this angle about its
#: z (``ChainParams.carry_goal_symmetry``): a block seats the same turned by pi, and Grasp's jaws leave it 10-15 deg
#: off its yaw and tilted along its length.
CARRY_GOAL_SYMMETRY = {"building_blocks": np.pi}
#: The Building Blocks approach hands over only with the hand within this angle (rad) of its held orientation and
#: its centre slower than this speed (m/s) (``ChainParams.handover_angle``, ``handover_speed``). The carry turns the
#: hand as the block in it turns; handed over on position alone, it left the hand still turning at 0.3-0.5 rad/s
#: with the block turning in the pinch (traced: the main command's seed 15), and Insert's wrist held a turn that no
#: longer matched the block. Insert's env starts from a carry done at rest (``tasks/carry.carry_to_goal``). At rest the
#: OSC holds the hand 1-3 deg off its held orientation, more with a block in hand (a steady-state error: its task-space
#: PD has no integral term), so some approaches end by their timeout (``APPROACH_TIMEOUT``), the hand at rest; the
#: wrist IK then takes the rest of the turn. Traced in the main command (seeds 4, 12, 15, 28), 6 of 24 approaches
#: ended so, 2.2-6.4 deg off, 3 of them the 4 carries. A looser angle, ending them sooner, has not been measured.
HANDOVER_SETTLE = {"building_blocks": (0.035, 0.02)}
#: The time (s) an episode's limit allows per approach; for Building Blocks also the approach's timeout, after which
#: it hands over where the hand is (fingers curled by an untrained Search caught on the pile and held the Orient
#: approach, and the chain, for good). Tool approaches have no timeout (their figures were measured without).
APPROACH_TIMEOUT = 3.0
TIMEOUT_FAMILIES = ("building_blocks",)
#: A Building Blocks episode ends this long (s) after the chain is done -- its last stage has used its step budget
#: with no feasibility switch left to restart a stage -- for a released block to come to rest. Before, Insert's policy
#: ran on, past the 125 steps it was trained for, until the episode's limit (40 s with 3 switches): the limit, not the
#: chain, set the length of most episodes. A tool episode ends at the first tick the chain is done: before, tool
#: Reorient's gait ran on past its 125 steps to the limit, 3 s longer in the sequential row and up to 18 s longer with
#: 3 switches allowed, so rows with other switch caps were not comparable (12 of the sequential row's 43 held-out
#: successes came in that overtime).
DONE_SETTLE = {"building_blocks": 1.0, "tool_positioning": 1 / 60}
