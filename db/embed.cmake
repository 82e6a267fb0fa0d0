# Turns the migration files (FILES, sorted, separated by "|") into a C array
# of SQL strings (OUT) so that every binary carries the schema it expects.
string(REPLACE "|" ";" FILES "${FILES}")
set(body "")
set(n 0)
foreach(f ${FILES})
  file(READ ${f} sql HEX)
  string(REGEX REPLACE "([0-9a-f][0-9a-f])" "0x\\1," sql "${sql}")
  get_filename_component(name ${f} NAME)
  string(APPEND body "static const char m${n}[] = {${sql}0};\n")
  string(APPEND names "    {\"${name}\", m${n}},\n")
  math(EXPR n "${n}+1")
endforeach()
file(WRITE ${OUT} "/* Generated from db/migrations by db/embed.cmake. */\n#include \"migrations.h\"\n${body}\nconst struct db_migration db_migrations[] = {\n${names}};\nconst int db_migration_count = ${n};\n")
