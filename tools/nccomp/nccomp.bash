# bash completion for nccomp(1). The subcommands and their options are read from `nccomp --help`
# and `nccomp SUBCOMMAND --help`, so they cannot drift from the installed binary; other words
# complete as file names. Installed as /usr/share/bash-completion/completions/nccomp.

_nccomp() {
  local cur=${COMP_WORDS[COMP_CWORD]}
  local cmd=${COMP_WORDS[0]}
  local sub="" i
  for ((i = 1; i < COMP_CWORD; i++)); do
    if [[ ${COMP_WORDS[i]} != -* ]]; then
      sub=${COMP_WORDS[i]}
      break
    fi
  done
  COMPREPLY=()
  if [[ -z $sub ]]; then
    local words
    if [[ $cur == -* ]]; then
      words="--help --version"
    else
      words=$("$cmd" --help 2>/dev/null |
        sed -n '/^Subcommands:/,$ s/^  \([a-z][a-z0-9-]*\) .*/\1/p')
    fi
    mapfile -t COMPREPLY < <(compgen -W "$words" -- "$cur")
  elif [[ $cur == -* ]]; then
    local opts
    opts=$("$cmd" "$sub" --help 2>/dev/null | sed -n 's/^ \{2,\}\(-[^ ]*\).*/\1/p' | tr ',' ' ')
    mapfile -t COMPREPLY < <(compgen -W "$opts" -- "$cur")
  fi
  return 0
}

complete -o bashdefault -o default -F _nccomp nccomp
