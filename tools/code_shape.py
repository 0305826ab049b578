#!/usr/bin/env python3
"""The code's shape (issue 33; STYLE.md): no function in sim/, plan/ or engine/ over 150 lines, no file
in engine/ over 900 lines, ns_step (sim/step.c) at most 60 lines.

    python3 tools/code_shape.py [ROOT]      # lists what breaks a bar; exit 1 if anything does
    python3 tools/code_shape.py --list ROOT # every function over 100 lines, longest first

A function is counted from the line that opens it (its name and parameters, at column 0)
to its closing brace at column 0, both included."""
import os
import re
import sys

FUNCTION_MAX = 150
ENGINE_FILE_MAX = 900
STEP_MAX = 60
START = re.compile(r'^(?!static\s+inline)[A-Za-z_][A-Za-z0-9_ \*]*?\b([A-Za-z_][A-Za-z0-9_]*)\s*\(')


def functions(path):
    """(name, first line, length) of each function defined at column 0 in a C file."""
    lines = open(path, encoding='utf-8', errors='replace').read().split('\n')
    out = []
    i = 0
    while i < len(lines):
        m = START.match(lines[i])
        if m and not lines[i].rstrip().endswith(';') and not lines[i].startswith(('typedef', 'struct', 'enum', '#')):
            # the body opens at a line that is '{' at column 0 (after the parameters)
            j = i
            while j < len(lines) and lines[j] != '{' and not lines[j].rstrip().endswith(';'):
                j += 1
            if j < len(lines) and lines[j] == '{':
                k = j + 1
                while k < len(lines) and lines[k] != '}':
                    k += 1
                out.append((m.group(1), i + 1, k - i + 1))
                i = k + 1
                continue
        i += 1
    return out


def main(argv):
    listing = '--list' in argv
    args = [a for a in argv if a != '--list']
    root = args[0] if args else os.path.join(os.path.dirname(os.path.abspath(__file__)), '..')
    bad = []
    every = []
    for folder in ('sim', 'plan', 'engine'):
        d = os.path.join(root, folder)
        for name in sorted(os.listdir(d)):
            if not name.endswith('.c'):
                continue
            path = os.path.join(d, name)
            rel = folder + '/' + name
            n = sum(1 for _ in open(path, encoding='utf-8', errors='replace'))
            if folder == 'engine' and n > ENGINE_FILE_MAX:
                bad.append(f'{rel}: {n} lines (at most {ENGINE_FILE_MAX} in engine/)')
            for fn, line, length in functions(path):
                every.append((length, f'{rel}:{line}: {fn}'))
                if length > FUNCTION_MAX:
                    bad.append(f'{rel}:{line}: {fn} is {length} lines (at most {FUNCTION_MAX})')
                if fn == 'ns_step' and length > STEP_MAX:
                    bad.append(f'{rel}:{line}: ns_step is {length} lines (at most {STEP_MAX})')
    if listing:
        for length, where in sorted(every, reverse=True):
            if length > 100:
                print(f'{length:5d}  {where}')
    for b in bad:
        print(b)
    print(f'{len(every)} functions checked, {len(bad)} over a bar')
    return 1 if bad else 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
