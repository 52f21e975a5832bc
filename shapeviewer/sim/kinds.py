"""Shape kinds by name: the hand-made map of YCB objects to the kinds of the procedural household
families, and the words of other objects' names (URDF folders) that tell their kind."""

from __future__ import annotations

import re

_YCB_KINDS = {
    "can": "002_master_chef_can 005_tomato_soup_can 007_tuna_fish_can 010_potted_meat_can",
    "box": "003_cracker_box 004_sugar_box 008_pudding_box 009_gelatin_box 026_sponge 036_wood_block 061_foam_brick "
    "062_dice 070-a_colored_wood_blocks 070-b_colored_wood_blocks 071_nine_hole_peg_test 077_rubiks_cube",
    "bottle": "006_mustard_bottle 021_bleach_cleanser",
    "spray_bottle": "022_windex_bottle",
    "banana": "011_banana",
    "fruit": "012_strawberry 013_apple 014_lemon 015_peach 016_pear 017_orange 018_plum",
    "pitcher": "019_pitcher_base",
    "bowl": "024_bowl",
    "mug": "025_mug",
    "plate": "029_plate",
    "cup": "065-a_cups 065-b_cups 065-c_cups 065-d_cups 065-e_cups 065-f_cups 065-g_cups 065-h_cups "
    "065-i_cups 065-j_cups",
    "drill": "035_power_drill",
    "tool": "030_fork 031_spoon 032_knife 033_spatula 037_scissors 040_large_marker 042_adjustable_wrench "
    "043_phillips_screwdriver 044_flat_screwdriver 048_hammer 050_medium_clamp 051_large_clamp "
    "052_extra_large_clamp",
    "ball": "053_mini_soccer_ball 054_softball 055_baseball 056_tennis_ball 057_racquetball 058_golf_ball "
    "063-a_marbles 063-b_marbles",
    "other": "028_skillet_lid 038_padlock 059_chain 072-a_toy_airplane 072-b_toy_airplane 072-c_toy_airplane "
    "072-d_toy_airplane 072-e_toy_airplane 073-a_lego_duplo 073-b_lego_duplo 073-c_lego_duplo "
    "073-d_lego_duplo 073-e_lego_duplo 073-f_lego_duplo 073-g_lego_duplo",
}
YCB_KIND = {obj: kind for kind, names in _YCB_KINDS.items() for obj in names.split()}
# YCB objects by their name without the number (``mustard_bottle`` -> ``006_mustard_bottle``): object
# sets that hold YCB meshes name them so.
_YCB_BY_SHORT = {obj.split("_", 1)[1]: obj for obj in YCB_KIND}

# Kinds an object's name tells (objects of URDF folders), in the vocabulary of household.KINDS: a word
# of the name that names a container or a tool. First match wins, in this order.
_KIND_WORDS = (
    ("spray_bottle", "spray"),
    ("mug", "mug mugs"),
    ("cup", "cup cups glass tumbler"),
    ("bowl", "bowl bowls"),
    ("plate", "plate plates dish saucer"),
    ("pitcher", "pitcher jug"),
    ("jar", "jar jars"),
    ("bottle", "bottle bottles flask shampoo cleanser detergent wash gel"),
    ("can", "can cans tin cylinder"),
    ("box", "box boxes carton cube tetra"),
    ("drill", "drill"),
    ("tool", "hammer screwdriver wrench pliers scissors clamp spatula knife fork spoon ladle marker"),
    ("ball", "ball"),
)
KIND_WORD = {w: kind for kind, words in _KIND_WORDS for w in words.split()}
# Whole names of produce: only a name made of these words is the kind (``nutrigrain_apple_cinnamon`` is
# a box of bars, not a fruit).
_PRODUCE_WORDS = {
    "banana": "banana bananas",
    "fruit": "apple lemon lime orange peach pear plum strawberry avocado starfruit pumpkin bell pepper "
    "red green yellow",
}
PRODUCE_WORD = {w: kind for kind, words in _PRODUCE_WORDS.items() for w in words.split()}
# Phrases whose words would say another kind (a watering can is not a can).
_NOT_A_KIND = (("watering", "can"), ("toilet", "paper"), ("light", "bulb"))
# Words that name a version of a model, not the object (``Shampoo_800_tex``, ``bowl_poisson_005``).
_NAME_NOISE = {"poisson", "tex", "new", "small", "large", "big"}


def name_words(name: str) -> list[str]:
    """The lower-case words of an object's file name: split at ``_``, ``-``, spaces and camel case,
    without numbers, single letters and version words (``RedCup_800_tex`` -> ``[red, cup]``)."""
    words = re.findall(r"[A-Z]?[a-z]+|[A-Z]+(?![a-z])|\d+", name)
    return [w.lower() for w in words if len(w) > 1 and not w.isdigit() and w.lower() not in _NAME_NOISE]


def kind_from_name(name: str) -> str:
    """The shape kind an object's file name tells (``tomato_soup_can`` -> ``can``, ``RedCup_800_tex``
    -> ``cup``, ``banana_poisson_001`` -> ``banana``, ``apple`` -> ``fruit``), else ``other``."""
    words = name_words(name)
    pairs = set(zip(words, words[1:]))
    if any(p in pairs for p in _NOT_A_KIND):
        return "other"
    for w in words:
        if w in KIND_WORD:
            return KIND_WORD[w]
    kinds = {PRODUCE_WORD.get(w) for w in words}
    if len(kinds) == 1 and None not in kinds:
        return str(kinds.pop())
    return "other"
