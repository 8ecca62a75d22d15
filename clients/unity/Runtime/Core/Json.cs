using System;
using System.Collections;
using System.Collections.Generic;
using System.Globalization;
using System.Text;

namespace Vista.Client
{
    /// <summary>
    /// A small, strict JSON (RFC 8259) reader and writer. Objects parse to
    /// <c>Dictionary&lt;string, object&gt;</c>, arrays to <c>List&lt;object&gt;</c>, strings to
    /// <c>string</c>, integers to <c>long</c> (or <c>double</c> past its range), other numbers to
    /// <c>double</c>, literals to <c>bool</c> and <c>null</c>. Numbers use the invariant culture.
    /// </summary>
    public static class Json
    {
        /// <summary>Deepest nesting of arrays and objects <see cref="Parse"/> accepts.</summary>
        public const int MaxDepth = 256;

        /// <summary>Parses one JSON text; throws <see cref="FormatException"/> (with the
        /// character position) when it is not valid JSON.</summary>
        public static object Parse(string text)
        {
            if (text == null)
            {
                throw new ArgumentNullException("text");
            }
            var reader = new Reader(text);
            reader.SkipWhitespace();
            object value = reader.ReadValue(0);
            reader.SkipWhitespace();
            if (!reader.AtEnd)
            {
                throw reader.Error("unexpected text after the JSON value");
            }
            return value;
        }

        /// <summary>Parses a JSON text that must be an object.</summary>
        public static Dictionary<string, object> ParseObject(string text)
        {
            var value = Parse(text) as Dictionary<string, object>;
            if (value == null)
            {
                throw new FormatException("expected a JSON object");
            }
            return value;
        }

        /// <summary>Writes a value as compact JSON: null, strings, booleans, numbers,
        /// dictionaries (keys written as strings) and other enumerables (as arrays).</summary>
        public static string Serialize(object value)
        {
            var output = new StringBuilder();
            Write(output, value, 0);
            return output.ToString();
        }

        static void Write(StringBuilder output, object value, int depth)
        {
            if (depth > MaxDepth)
            {
                throw new ArgumentException("the value nests deeper than " + MaxDepth + " levels");
            }
            if (value == null)
            {
                output.Append("null");
            }
            else if (value is string)
            {
                WriteString(output, (string)value);
            }
            else if (value is bool)
            {
                output.Append((bool)value ? "true" : "false");
            }
            else if (value is double || value is float || value is decimal)
            {
                WriteReal(output, Convert.ToDouble(value, CultureInfo.InvariantCulture));
            }
            else if (IsInteger(value))
            {
                output.Append(Convert.ToString(value, CultureInfo.InvariantCulture));
            }
            else if (value is IDictionary)
            {
                WriteObject(output, (IDictionary)value, depth);
            }
            else if (value is IEnumerable)
            {
                WriteArray(output, (IEnumerable)value, depth);
            }
            else
            {
                throw new ArgumentException("cannot write a " + value.GetType().Name + " as JSON");
            }
        }

        static bool IsInteger(object value)
        {
            return value is int || value is long || value is short || value is byte
                || value is sbyte || value is uint || value is ulong || value is ushort;
        }

        static void WriteReal(StringBuilder output, double number)
        {
            if (double.IsNaN(number) || double.IsInfinity(number))
            {
                throw new ArgumentException("JSON has no NaN or infinity");
            }
            output.Append(number.ToString("R", CultureInfo.InvariantCulture));
        }

        static void WriteObject(StringBuilder output, IDictionary members, int depth)
        {
            output.Append('{');
            bool first = true;
            foreach (DictionaryEntry member in members)
            {
                if (!first)
                {
                    output.Append(',');
                }
                first = false;
                WriteString(output, Convert.ToString(member.Key, CultureInfo.InvariantCulture));
                output.Append(':');
                Write(output, member.Value, depth + 1);
            }
            output.Append('}');
        }

        static void WriteArray(StringBuilder output, IEnumerable items, int depth)
        {
            output.Append('[');
            bool first = true;
            foreach (object item in items)
            {
                if (!first)
                {
                    output.Append(',');
                }
                first = false;
                Write(output, item, depth + 1);
            }
            output.Append(']');
        }

        static void WriteString(StringBuilder output, string text)
        {
            output.Append('"');
            for (int i = 0; i < text.Length; i++)
            {
                char c = text[i];
                switch (c)
                {
                    case '"': output.Append("\\\""); break;
                    case '\\': output.Append("\\\\"); break;
                    case '\b': output.Append("\\b"); break;
                    case '\f': output.Append("\\f"); break;
                    case '\n': output.Append("\\n"); break;
                    case '\r': output.Append("\\r"); break;
                    case '\t': output.Append("\\t"); break;
                    default:
                        if (c < 0x20 || IsLoneSurrogate(text, i))
                        {
                            output.Append("\\u").Append(((int)c).ToString("x4", CultureInfo.InvariantCulture));
                        }
                        else
                        {
                            output.Append(c);
                        }
                        break;
                }
            }
            output.Append('"');
        }

        /// <summary>A surrogate without its partner cannot be encoded as UTF-8: it is escaped.</summary>
        static bool IsLoneSurrogate(string text, int i)
        {
            char c = text[i];
            if (char.IsHighSurrogate(c))
            {
                return i + 1 >= text.Length || !char.IsLowSurrogate(text[i + 1]);
            }
            if (char.IsLowSurrogate(c))
            {
                return i == 0 || !char.IsHighSurrogate(text[i - 1]);
            }
            return false;
        }

        sealed class Reader
        {
            readonly string text;
            int position;

            public Reader(string text)
            {
                this.text = text;
            }

            public bool AtEnd
            {
                get { return position >= text.Length; }
            }

            public FormatException Error(string what)
            {
                return new FormatException("JSON: " + what + " at character " + position);
            }

            public void SkipWhitespace()
            {
                while (position < text.Length)
                {
                    char c = text[position];
                    if (c != ' ' && c != '\t' && c != '\n' && c != '\r')
                    {
                        return;
                    }
                    position++;
                }
            }

            public object ReadValue(int depth)
            {
                if (AtEnd)
                {
                    throw Error("unexpected end of text");
                }
                char c = text[position];
                switch (c)
                {
                    case '{': return ReadObject(depth + 1);
                    case '[': return ReadArray(depth + 1);
                    case '"': return ReadString();
                    case 't': ReadLiteral("true"); return true;
                    case 'f': ReadLiteral("false"); return false;
                    case 'n': ReadLiteral("null"); return null;
                    default:
                        if (c == '-' || (c >= '0' && c <= '9'))
                        {
                            return ReadNumber();
                        }
                        throw Error("unexpected character '" + c + "'");
                }
            }

            void CheckDepth(int depth)
            {
                if (depth > MaxDepth)
                {
                    throw Error("nesting deeper than " + MaxDepth + " levels");
                }
            }

            Dictionary<string, object> ReadObject(int depth)
            {
                CheckDepth(depth);
                var members = new Dictionary<string, object>();
                position++;
                SkipWhitespace();
                if (Peek() == '}')
                {
                    position++;
                    return members;
                }
                while (true)
                {
                    SkipWhitespace();
                    if (Peek() != '"')
                    {
                        throw Error("expected a member name");
                    }
                    string name = ReadString();
                    SkipWhitespace();
                    Expect(':');
                    SkipWhitespace();
                    members[name] = ReadValue(depth);
                    SkipWhitespace();
                    if (Peek() == ',')
                    {
                        position++;
                        continue;
                    }
                    Expect('}');
                    return members;
                }
            }

            List<object> ReadArray(int depth)
            {
                CheckDepth(depth);
                var items = new List<object>();
                position++;
                SkipWhitespace();
                if (Peek() == ']')
                {
                    position++;
                    return items;
                }
                while (true)
                {
                    SkipWhitespace();
                    items.Add(ReadValue(depth));
                    SkipWhitespace();
                    if (Peek() == ',')
                    {
                        position++;
                        continue;
                    }
                    Expect(']');
                    return items;
                }
            }

            string ReadString()
            {
                position++;
                var value = new StringBuilder();
                while (true)
                {
                    if (AtEnd)
                    {
                        throw Error("unterminated string");
                    }
                    char c = text[position++];
                    if (c == '"')
                    {
                        return value.ToString();
                    }
                    if (c < 0x20)
                    {
                        throw Error("unescaped control character in a string");
                    }
                    if (c != '\\')
                    {
                        value.Append(c);
                        continue;
                    }
                    if (AtEnd)
                    {
                        throw Error("unterminated escape");
                    }
                    char escape = text[position++];
                    switch (escape)
                    {
                        case '"': value.Append('"'); break;
                        case '\\': value.Append('\\'); break;
                        case '/': value.Append('/'); break;
                        case 'b': value.Append('\b'); break;
                        case 'f': value.Append('\f'); break;
                        case 'n': value.Append('\n'); break;
                        case 'r': value.Append('\r'); break;
                        case 't': value.Append('\t'); break;
                        case 'u': value.Append(ReadHexUnit()); break;
                        default: throw Error("unknown escape '\\" + escape + "'");
                    }
                }
            }

            char ReadHexUnit()
            {
                if (position + 4 > text.Length)
                {
                    throw Error("truncated \\u escape");
                }
                int unit;
                if (!int.TryParse(text.Substring(position, 4), NumberStyles.AllowHexSpecifier,
                        CultureInfo.InvariantCulture, out unit))
                {
                    throw Error("bad \\u escape");
                }
                position += 4;
                return (char)unit;
            }

            object ReadNumber()
            {
                int start = position;
                bool integral = true;
                if (Peek() == '-')
                {
                    position++;
                }
                if (Peek() == '0')
                {
                    position++;
                }
                else if (!ReadDigits())
                {
                    throw Error("expected a digit");
                }
                if (Peek() == '.')
                {
                    integral = false;
                    position++;
                    if (!ReadDigits())
                    {
                        throw Error("expected a digit after the decimal point");
                    }
                }
                if (Peek() == 'e' || Peek() == 'E')
                {
                    integral = false;
                    position++;
                    if (Peek() == '+' || Peek() == '-')
                    {
                        position++;
                    }
                    if (!ReadDigits())
                    {
                        throw Error("expected a digit in the exponent");
                    }
                }
                string literal = text.Substring(start, position - start);
                long whole;
                if (integral && long.TryParse(literal, NumberStyles.AllowLeadingSign,
                        CultureInfo.InvariantCulture, out whole))
                {
                    return whole;
                }
                double real;
                if (!double.TryParse(literal, NumberStyles.Float, CultureInfo.InvariantCulture, out real)
                    || double.IsInfinity(real))
                {
                    throw Error("number out of range");
                }
                return real;
            }

            bool ReadDigits()
            {
                int start = position;
                while (position < text.Length && text[position] >= '0' && text[position] <= '9')
                {
                    position++;
                }
                return position > start;
            }

            void ReadLiteral(string literal)
            {
                if (string.CompareOrdinal(text, position, literal, 0, literal.Length) != 0)
                {
                    throw Error("expected '" + literal + "'");
                }
                position += literal.Length;
            }

            char Peek()
            {
                return AtEnd ? '\0' : text[position];
            }

            void Expect(char c)
            {
                if (Peek() != c)
                {
                    throw Error("expected '" + c + "'");
                }
                position++;
            }
        }
    }
}
