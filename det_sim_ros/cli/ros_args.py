"""
ROS arguments on a command line, checked before rcl reads them.

sim_node and ``det_sim replay play`` pass theirs to rcl, whose lexer refuses a ``-p`` or ``-r``
rule without ``:=`` with an error about lexeme types; :func:`ros_rule_error` says it plainly.
"""

# the ROS arguments that take a NAME:=VALUE rule; rcl's lexer refuses a rule without ':='
# with an error about lexeme types
ROS_RULES = {'-p': ('a parameter', 'NAME:=VALUE'), '--param': ('a parameter', 'NAME:=VALUE'),
             '-r': ('a remap', 'FROM:=TO'), '--remap': ('a remap', 'FROM:=TO')}


def ros_rule_error(argv) -> str:
    """
    Return one line on the first ``-p`` / ``-r`` rule without ``:=`` among ROS arguments, or ''.

    ``argv`` is a command line without its program name; the ROS arguments are those after
    ``--ros-args`` (up to a ``--``). ``-p mode=free_run`` gives
    "-p mode=free_run: a parameter is -p NAME:=VALUE, with ':=' (-p mode:=free_run)".
    """
    in_ros = False
    args = iter(argv)
    for arg in args:
        if arg == '--ros-args':
            in_ros = True
        elif arg == '--':
            in_ros = False
        elif in_ros and arg in ROS_RULES:
            what, form = ROS_RULES[arg]
            rule = next(args, None)
            if rule is None:
                return f'{arg} needs a rule after it: {what} is {arg} {form}'
            if ':=' not in rule:
                name, sep, value = rule.partition('=')
                hint = f' ({arg} {name}:={value})' if sep and name else ''
                return f"{arg} {rule}: {what} is {arg} {form}, with ':='{hint}"
    return ''
